// `Raster<Layout>`, the compositing loops over a tile in steps of 8 or 16 pixel lanes. No
// include guard: dispatch.hpp includes this file once per instruction set, each time inside
// its own namespace and `#pragma GCC target` region, so that every function of the
// templates, helpers included, is compiled for that instruction set (a target attribute on
// an outer function alone lets GCC lower the wide vector compares of the helpers to scalar
// code before inlining them). Include raster.hpp first.

// One step of the compositing loops over L pixels of the tile state.
template <int L>
struct Lanes {
    static constexpr int kWidth = L;
    typedef typename Vectors<L>::f vf;
    typedef typename Vectors<L>::i vi;

    static vf splat(float x) { return vf{} + x; }
    static vi splat_i(int32_t x) { return vi{} + x; }
    static vf load(const float* p) {
        vf v;
        std::memcpy(&v, p, sizeof v);
        return v;
    }
    static vi load(const int32_t* p) {
        vi v;
        std::memcpy(&v, p, sizeof v);
        return v;
    }
    static void store(float* p, vf v) { std::memcpy(p, &v, sizeof v); }
    static void store(int32_t* p, vi v) { std::memcpy(p, &v, sizeof v); }
    // Bit i: lane i of the mask m (0 or -1) is set; a movemask where the target has one
    // (GCC's generic code moves the lanes out one by one).
    static uint32_t bits(vi m) {
#ifdef __x86_64__
        if constexpr (L == 4) return uint32_t(_mm_movemask_ps((__m128)m));
        if constexpr (L == 8) return uint32_t(_mm256_movemask_ps((__m256)m));
        if constexpr (L == 16) return uint32_t(_mm512_movepi32_mask((__m512i)m));
#endif
        uint32_t b = 0;
        for (int i = 0; i < L; ++i) b |= uint32_t(m[i] & 1) << i;
        return b;
    }
    static bool any(vi m) { return bits(m) != 0; }
    static vf max(vf a, vf b) { return a > b ? a : b; }

    // exp for the Gaussian falloff (Cephes expf polynomial, about 1 ulp, exp(0) == 1
    // exactly). NaN and large |x| map to the clamp bounds.
    static vf falloff_exp(vf x) {
        x = x > splat(-87.0f) ? x : splat(-87.0f);
        x = x < splat(88.0f) ? x : splat(88.0f);
        const vf n = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;  // round
        vf r = x - n * 0.693359375f;
        r = r - n * -2.12194440e-4f;
        vf p = splat(1.9875691500e-4f);
        p = p * r + 1.3981999507e-3f;
        p = p * r + 8.3334519073e-3f;
        p = p * r + 4.1665795894e-2f;
        p = p * r + 1.6666665459e-1f;
        p = p * r + 5.0000001201e-1f;
        const vf y = p * (r * r) + r + 1.0f;
        const vi bits = (__builtin_convertvector(n, vi) + 127) << 23;
        return y * (vf)bits;
    }

    // alpha of one Gaussian at L pixel centres; forward and backward share it so that
    // their skip decisions agree bit for bit.
    struct Falloff {
        vf dx, power, vis, a;
        vi ok;  // power <= 0 and a >= 1/255 (also false for NaN)
    };

    // dy: a float (one row) or a vector (a row per lane).
    template <class DY>
    static Falloff falloff(const TileSplat& s, vf px_centre, DY dy) {
        Falloff f;
        f.dx = s.x - px_centre;
        f.power = -0.5f * (s.ca * f.dx * f.dx + s.cc * dy * dy) - s.cb * f.dx * dy;
        f.vis = falloff_exp(f.power);
        const vf t = s.op * f.vis;
        f.a = t < kAlphaMax ? t : splat(kAlphaMax);
        f.ok = (f.power <= 0.0f) & (f.a >= kAlphaMin);
        return f;
    }

    // Pixel centres of columns first .. first + L - 1 (exact: small integers and halves).
    static vf lane_centres(int first) {
        vf c;
        for (int i = 0; i < L; ++i) c[i] = float(first + i) + 0.5f;
        return c;
    }

    // The tile's per-pixel state, rows of kTile pixels.
    struct ForwardState {
        float *T, *cr, *cg, *cb, *cz;
        int32_t *last, *live;
    };

    // Composites sample j (1-based count jj) of Gaussian s into the L pixels at p, those of
    // them in `valid`; returns the lanes that composited it (-1) for the lane counts.
    template <class DY>
    static vi forward_step(const ForwardState& S, const TileSplat& s, int p, vf centre, DY dy,
                           vi jj, vi valid) {
        const Falloff fo = falloff(s, centre, dy);
        const vi lv = load(S.live + p);
        const vf Tp = load(S.T + p);
        const vi ok = fo.ok & lv & valid;
        const vf nT = Tp * (1.0f - fo.a);
        const vi stop = ok & (nT < kTransmittanceMin);
        const vi use = ok & ~stop;
        const vf w = use ? fo.a * Tp : splat(0.0f);
        store(S.cr + p, load(S.cr + p) + w * s.r);
        store(S.cg + p, load(S.cg + p) + w * s.g);
        store(S.cb + p, load(S.cb + p) + w * s.b);
        store(S.cz + p, load(S.cz + p) + w * s.z);
        store(S.T + p, use ? nT : Tp);
        store(S.last + p, use ? jj : load(S.last + p));
        store(S.live + p, lv & ~stop);
        return use;
    }

    static int64_t count(vi used) {  // used: minus the number of lanes used, per lane
        int64_t n = 0;
        for (int i = 0; i < L; ++i) n -= used[i];
        return n;
    }

    struct BackwardState {
        float *T, *behind;
        const float *gr, *gg, *gb, *gz;
        const int32_t* last;
    };

    // Gradients of the falloff power p = -(ca dx^2 + 2 cb dx dy + cc dy^2) / 2 enter through
    // its moments: m_x = sum dp dx, m_y = sum dp dy, m_xx, m_xy, m_yy.
    struct Moments {
        vf m_x{}, m_y{}, m_xx{}, m_xy{}, m_yy{}, d_op{}, d_r{}, d_g{}, d_b{}, d_z{};

        // Lane sums: m_x, m_y, m_xx, m_xy, m_yy, d_op, d_r, d_g, d_b, d_z.
        void sums(float* out) const {
            vf v[kEntryGrad] = {m_x, m_y, m_xx, m_xy, m_yy, d_op, d_r, d_g, d_b, d_z};
            reduce<L>(v, kEntryGrad);
            for (int c = 0; c < kEntryGrad; ++c) out[c] = v[c / L][c % L];
        }
    };

    // The lane sums of many vectors together, a transpose-like tree: while each of the n
    // vectors' sums is spread over segments of S lanes, one fold adds the segments' halves of
    // two vectors and packs the results into one vector, halving S and n. Ends with the sums
    // in lane order, L to a vector.
    template <int S>
    static void reduce(vf* v, int n) {
        if constexpr (S > 1) {
            for (int i = 0; i < n; i += 2)
                v[i / 2] = fold<S>(v[i], i + 1 < n ? v[i + 1] : vf{},
                                   std::make_integer_sequence<int, L>());
            reduce<S / 2>(v, (n + 1) / 2);
        }
    }
    // Output lane o takes, from a (first half) or b, segment o / (S/2) of its half's vector:
    // its lane o % (S/2) plus the lane S/2 above.
    static constexpr int fold_lane(int S, int o, int upper) {
        const int h = S / 2, in = o % (L / 2);
        return (o < L / 2 ? 0 : L) + in / h * S + in % h + upper * h;
    }
    template <int S, int... O>
    static vf fold(vf a, vf b, std::integer_sequence<int, O...>) {
        return __builtin_shufflevector(a, b, fold_lane(S, O, 0)...) +
               __builtin_shufflevector(a, b, fold_lane(S, O, 1)...);
    }

    // Un-composites sample j (index jj) of Gaussian s at the L pixels at p (those in
    // `valid`), back to front.
    template <class DY>
    static void backward_step(const BackwardState& S, Moments& M, const TileSplat& s, int p,
                              vf centre, DY dy, vi jj, vi valid) {
        const Falloff fo = falloff(s, centre, dy);
        const vi ok = fo.ok & (jj < load(S.last + p)) & valid;
        const vf a = ok ? fo.a : splat(0.0f);
        const vf inv_one_minus = 1.0f / (1.0f - a);
        const vf Tj = load(S.T + p) * inv_one_minus;
        const vf pr = load(S.gr + p), pg = load(S.gg + p), pb = load(S.gb + p);
        const vf pz = load(S.gz + p);
        const vf gp = pr * s.r + pg * s.g + pb * s.b + pz * s.z;
        const vf w = a * Tj;
        const vf beh = load(S.behind + p);
        const vf d_alpha = Tj * gp - beh * inv_one_minus;
        store(S.behind + p, beh + w * gp);
        store(S.T + p, Tj);
        M.d_r += pr * w;
        M.d_g += pg * w;
        M.d_b += pb * w;
        M.d_z += pz * w;
        // alpha = min(0.99, op * vis): no gradient through the clamp
        const vf da = ok & (s.op * fo.vis <= kAlphaMax) ? d_alpha : splat(0.0f);
        M.d_op += da * fo.vis;
        const vf d_pow = da * fo.a;
        const vf wx = d_pow * fo.dx, wy = d_pow * dy;
        M.m_x += wx;
        M.m_y += wy;
        M.m_xx += wx * fo.dx;
        M.m_xy += wx * dy;
        M.m_yy += wy * dy;
    }
};

// The step layouts. A layout numbers the steps of a Gaussian's box (bit k of a 64-bit step
// mask); `steps` runs the forward's (those the Gaussian's ellipse reaches, in rows with a
// live pixel) as step(k, p, centre, dy, valid), and `masked_steps` the steps of a mask in the
// same order as step(p, centre, dy, valid): the backward's, those in which the forward
// composited a sample (exactly where it un-composites one: it skips no other lane).

// Row-major tile state, one chunk of L pixels of one row per step (AVX2: 8; baseline: 4,
// as SSE2 has no 8-lane compares and GCC would split them into scalar code).
template <int L>
struct RowSteps {
    typedef Lanes<L> V;
    static constexpr int kSize = kTilePixels;
    static constexpr int kGroups = 1;          // live-row masks (bit py), all columns
    static constexpr int kPerRow = kTile / L;  // steps in a row at most: k = py kPerRow + i
    static int at(int px, int py) { return py * kTile + px; }
    static void live_rows(const int32_t* live, uint32_t* rows) {
        rows[0] = 0;
        for (int py = 0; py < kTile; ++py) {
            typename V::vi row{};
            for (int h = 0; h < kTile / L; ++h) row |= V::load(live + at(L * h, py));
            rows[0] |= uint32_t(V::any(row)) << py;
        }
    }
    // Chunk i of a row starts at column col, a multiple of 4 (a box's span rounded to 4
    // pixels, not L), and its step at start, shifted back to stay inside the row, with the
    // columns an earlier chunk covered masked off.
    struct Chunk {
        int col, start;
        Chunk(const TileSplat& s, int i)
            : col((s.col0 & ~3) + L * i), start(std::min(col, kTile - L)) {}
    };
    static typename V::vi lanes() {
        typename V::vi lane;
        for (int i = 0; i < L; ++i) lane[i] = i;
        return lane;
    }
    template <class Step>
    static void steps(const TileSplat& s, bool ellipse, const uint32_t* live, Step step) {
        const Ellipse e(s, ellipse);
        for (int py = s.row0; py <= s.row1; ++py) {
            if (!((live[0] >> py) & 1)) continue;
            const float dy = s.y - (float(py) + 0.5f);
            for (int i = 0; (s.col0 & ~3) + L * i <= s.col1; ++i) {
                const Chunk c(s, i);
                if (!e.reaches(dy, float(c.col) + 0.5f, float(c.start + L - 1) + 0.5f)) continue;
                step(py * kPerRow + i, at(c.start, py), V::lane_centres(c.start), dy,
                     lanes() >= c.col - c.start);
            }
        }
    }
    template <class Step>
    static void masked_steps(const TileSplat& s, uint64_t mask, Step step) {
        for (; mask; mask &= mask - 1) {
            const int k = __builtin_ctzll(mask), py = k / kPerRow;
            const Chunk c(s, k % kPerRow);
            step(at(c.start, py), V::lane_centres(c.start), s.y - (float(py) + 0.5f),
                 lanes() >= c.col - c.start);
        }
    }
};

// Tile state stored half by half (8 columns x 16 rows, then a padding row), so that two
// rows of one half are 16 contiguous values: one 16-lane step covers 8 columns x 2 rows,
// and a Gaussian takes up to ceil(rows / 2) steps per half its box reaches (AVX-512): step
// k = 8 h + i covers half h, rows row0 + 2 i and the next. (Pairs aligned to even rows
// evaluate more lanes and measured no faster.)
struct PairSteps {
    typedef Lanes<16> V;
    static constexpr int kHalf = 8 * (kTile + 1);
    static constexpr int kSize = 2 * kHalf;
    static constexpr int kGroups = 2;  // live-row masks (bit py), one per half
    static int at(int px, int py) { return (px / 8) * kHalf + py * 8 + px % 8; }
    static void live_rows(const int32_t* live, uint32_t* rows) {
        typedef Lanes<8> H;
        for (int h = 0; h < 2; ++h) {
            rows[h] = 0;
            for (int py = 0; py < kTile; ++py)
                rows[h] |= uint32_t(H::any(H::load(live + at(8 * h, py)))) << py;
        }
    }
    // The steps of s's box that its ellipse reaches (bit k), all 16 evaluated at once.
    static uint32_t reached(const TileSplat& s, const Ellipse& e) {
        V::vi h, i;
        for (int k = 0; k < 16; ++k) h[k] = k / 8, i[k] = k % 8;
        const V::vi py = s.row0 + 2 * i;
        const V::vi in_box = (py <= s.row1) & (h >= s.col0 / 8) & (h <= s.col1 / 8);
        if (e.box) return V::bits(in_box);
        const V::vf first = __builtin_convertvector(8 * h, V::vf) - 0.5f;  // a pixel wider
        const V::vf last = first + 9.0f;
        const auto row = [&](V::vf dy) {
            const V::vf c = e.x + e.slope * dy, w2 = (e.q - e.g * dy * dy) * e.inv_ca;
            const V::vf d = V::max(V::max(first - c, c - last), V::splat(0.0f));
            return w2 >= d * d;
        };
        const V::vf dy = s.y - (__builtin_convertvector(py, V::vf) + 0.5f);
        return V::bits(in_box & (row(dy) | ((py < s.row1) & row(dy - 1.0f))));
    }
    template <class Step>
    static void steps(const TileSplat& s, bool ellipse, const uint32_t* live, Step step) {
        for (uint32_t m = reached(s, Ellipse(s, ellipse)); m; m &= m - 1) {
            const int k = __builtin_ctz(m), py = s.row0 + 2 * (k % 8);
            const bool second = py < s.row1;
            if ((live[k / 8] >> py) & (second ? 3u : 1u))
                step_at(s, k, [&](auto... a) { step(k, a...); });
        }
    }
    template <class Step>
    static void masked_steps(const TileSplat& s, uint64_t mask, Step step) {
        for (; mask; mask &= mask - 1) step_at(s, __builtin_ctzll(mask), step);
    }
    // Step k of s as step(p, centre, dy, valid).
    template <class Step>
    static void step_at(const TileSplat& s, int k, Step&& step) {
        V::vf centre, row_offset;
        V::vi upper;  // the lanes of the pair's first row
        for (int l = 0; l < 16; ++l) {
            centre[l] = float(l % 8) + 0.5f;
            row_offset[l] = float(l / 8) + 0.5f;  // py + 1.5 == (py + 1) + 0.5 exactly
            upper[l] = l < 8 ? -1 : 0;
        }
        const int h = k / 8, py = s.row0 + 2 * (k % 8);
        const V::vf dy = s.y - (float(py) + row_offset);
        step(at(8 * h, py), centre + float(8 * h), dy, py < s.row1 ? V::splat_i(-1) : upper);
    }
};

// Compositing of a tile with the steps of Layout (RowSteps or PairSteps).
template <class Layout>
struct Raster {
    typedef typename Layout::V V;
    static constexpr int kSize = Layout::kSize;

    // Front-to-back compositing of one tile. Writes rgb/alpha/depth for the tile's pixels
    // and, for the backward pass, the per-pixel final transmittance and contributor count
    // and each Gaussian's mask of the steps that composited a sample (step_mask[j], left
    // as it is for Gaussians after the tile turned opaque); lanes[0] = pixel lanes
    // evaluated, lanes[1] = those that composited a sample. ellipse: skip the steps outside
    // each Gaussian's ellipse (Ellipse), else take every step of its box.
    static void composite_forward(const std::vector<TileSplat>& G, const TileFrame& f,
                                  const float* background, bool ellipse, float* rgb, float* alpha,
                                  float* depth, float* T_final, int32_t* last_out,
                                  uint64_t* step_mask, int64_t* lanes) {
        alignas(64) float T[kSize], cr[kSize], cg[kSize], cb[kSize], cz[kSize];
        alignas(64) int32_t live[kSize], last[kSize];
        std::fill_n(T, kSize, 1.0f);
        for (float* c : {cr, cg, cb, cz}) std::fill_n(c, kSize, 0.0f);
        std::fill_n(last, kSize, 0);
        std::fill_n(live, kSize, 0);  // padding and pixels outside the image stay 0
        for (int py = 0; py < kTile && f.oy + py < f.height; ++py)
            for (int px = 0; px < kTile && f.ox + px < f.width; ++px) live[Layout::at(px, py)] = -1;
        const typename V::ForwardState S{T, cr, cg, cb, cz, last, live};
        uint32_t live_rows[Layout::kGroups] = {};
        typename V::vi used{};
        int64_t steps = 0;
        const int64_t n = int64_t(G.size());
        for (int64_t j = 0; j < n; ++j) {
            if (j % kLiveCheck == 0) {
                Layout::live_rows(live, live_rows);
                uint32_t tile_live = 0;
                for (uint32_t rows : live_rows) tile_live |= rows;
                if (!tile_live) break;
            }
            const TileSplat& s = G[j];
            const typename V::vi jj = V::splat_i(int32_t(j + 1));
            uint64_t mask = 0;
            Layout::steps(s, ellipse, live_rows,
                          [&](int k, int p, typename V::vf centre, auto dy, typename V::vi valid) {
                              const typename V::vi use =
                                  V::forward_step(S, s, p, centre, dy, jj, valid);
                              used += use;
                              ++steps;
                              mask |= uint64_t(V::any(use)) << k;
                          });
            step_mask[j] = mask;
        }

        for (int py = 0; py < kTile && f.oy + py < f.height; ++py)
            for (int px = 0; px < kTile && f.ox + px < f.width; ++px) {
                const int p = Layout::at(px, py);
                const int64_t o = int64_t(f.oy + py) * f.width + (f.ox + px);
                rgb[3 * o] = cr[p] + T[p] * background[0];
                rgb[3 * o + 1] = cg[p] + T[p] * background[1];
                rgb[3 * o + 2] = cb[p] + T[p] * background[2];
                alpha[o] = 1.0f - T[p];
                depth[o] = cz[p];
                T_final[o] = T[p];
                last_out[o] = last[p];
            }
        lanes[0] = V::kWidth * steps;
        lanes[1] = V::count(used);
    }

    // Back-to-front pass over one tile, over the steps in which the forward composited a
    // sample: transmittance is recovered by dividing out each alpha, and the gradient of
    // everything behind a sample is carried as one scalar per pixel. Writes the kEntryGrad
    // floats of the tile's j-th entry at entry_grad + slot[j] * kEntryGrad.
    static void composite_backward(const std::vector<TileSplat>& G, const TileFrame& f,
                                   const float* background, const float* g_rgb,
                                   const float* g_alpha, const float* g_depth, const float* T_final,
                                   const int32_t* last_in, const uint64_t* step_mask,
                                   const int64_t* slot, float* entry_grad) {
        alignas(64) float T[kSize], behind[kSize], gr[kSize], gg[kSize], gb[kSize], gz[kSize];
        alignas(64) int32_t last[kSize];
        std::fill_n(T, kSize, 1.0f);
        for (float* c : {behind, gr, gg, gb, gz}) std::fill_n(c, kSize, 0.0f);
        std::fill_n(last, kSize, 0);  // no sample is drawn at padding or outside the image
        for (int py = 0; py < kTile && f.oy + py < f.height; ++py) {
            for (int px = 0; px < kTile && f.ox + px < f.width; ++px) {
                const int p = Layout::at(px, py);
                const int64_t o = int64_t(f.oy + py) * f.width + (f.ox + px);
                gr[p] = g_rgb[3 * o];
                gg[p] = g_rgb[3 * o + 1];
                gb[p] = g_rgb[3 * o + 2];
                gz[p] = g_depth ? g_depth[o] : 0.0f;
                const float ga = g_alpha ? g_alpha[o] : 0.0f;
                T[p] = T_final[o];
                // rgb = ... + T bg and alpha = 1 - T: dL/dT_final, times T_final.
                behind[p] =
                    (gr[p] * background[0] + gg[p] * background[1] + gb[p] * background[2] - ga) *
                    T[p];
                last[p] = last_in[o];
            }
        }

        const typename V::BackwardState S{T, behind, gr, gg, gb, gz, last};
        for (int64_t j = int64_t(G.size()) - 1; j >= 0; --j) {
            float* e = entry_grad + slot[j] * kEntryGrad;
            if (!step_mask[j]) {
                std::fill_n(e, kEntryGrad, 0.0f);
                continue;
            }
            const TileSplat& s = G[j];
            const typename V::vi jj = V::splat_i(int32_t(j));
            typename V::Moments M;
            Layout::masked_steps(s, step_mask[j],
                                 [&](int p, typename V::vf centre, auto dy, typename V::vi valid) {
                                     V::backward_step(S, M, s, p, centre, dy, jj, valid);
                                 });
            float m[kEntryGrad];
            M.sums(m);
            e[0] = -(s.ca * m[0] + s.cb * m[1]);  // dp/dmean_x = -(ca dx + cb dy)
            e[1] = -(s.cb * m[0] + s.cc * m[1]);
            e[2] = -0.5f * m[2];
            e[3] = -m[3];
            e[4] = -0.5f * m[4];
            std::copy(m + 5, m + kEntryGrad, e + 5);
        }
    }
};
