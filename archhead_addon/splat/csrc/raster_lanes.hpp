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
    static float lane_sum(vf v) {
        float s = 0.0f;
        for (int i = 0; i < L; ++i) s += v[i];
        return s;
    }
    static bool any(vi m) {
        int32_t s = 0;
        for (int i = 0; i < L; ++i) s |= m[i];
        return s != 0;
    }

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

        // Lane sums added to sums: m_x, m_y, m_xx, m_xy, m_yy, d_op, d_r, d_g, d_b, d_z.
        void add_to(float* sums) const {
            const vf* v[kEntryGrad] = {&m_x,  &m_y, &m_xx, &m_xy, &m_yy,
                                       &d_op, &d_r, &d_g,  &d_b,  &d_z};
            for (int c = 0; c < kEntryGrad; ++c) sums[c] += lane_sum(*v[c]);
        }
    };

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

// Row-major tile state, one chunk of L pixels of one row per step (AVX2: 8; baseline: 4,
// as SSE2 has no 8-lane compares and GCC would split them into scalar code).
template <int L>
struct RowSteps {
    typedef Lanes<L> V;
    static constexpr int kSize = kTilePixels;
    static int at(int px, int py) { return py * kTile + px; }
    static bool row_any(const int32_t* mask, int py) {
        typename V::vi row{};
        for (int h = 0; h < kTile / L; ++h) row |= V::load(mask + at(L * h, py));
        return V::any(row);
    }
    // step(p, centre, dy, valid) for each step of s's box in the rows with active(py). Steps
    // start at multiples of 4 columns (a box's span rounded to 4 pixels, not L), shifted
    // back to stay inside the row, with the columns an earlier step covered masked off.
    template <class Active, class Step>
    static void steps(const TileSplat& s, Active active, Step step) {
        typename V::vi lane;
        for (int i = 0; i < L; ++i) lane[i] = i;
        for (int py = s.row0; py <= s.row1; ++py) {
            if (!active(py)) continue;
            const float dy = s.y - (float(py) + 0.5f);
            for (int col = s.col0 & ~3; col <= s.col1;) {
                const int start = std::min(col, kTile - L);
                step(at(start, py), V::lane_centres(start), dy, lane >= col - start);
                col = start + L;
            }
        }
    }
};

// Tile state stored half by half (8 columns x 16 rows, then a padding row), so that two
// rows of one half are 16 contiguous values: one 16-lane step covers 8 columns x 2 rows,
// and a Gaussian takes ceil(rows / 2) steps per half its box reaches (AVX-512). (Pairs
// aligned to even rows evaluate more lanes and measured no faster.)
struct PairSteps {
    typedef Lanes<16> V;
    static constexpr int kHalf = 8 * (kTile + 1);
    static constexpr int kSize = 2 * kHalf;
    static int at(int px, int py) { return (px / 8) * kHalf + py * 8 + px % 8; }
    static bool row_any(const int32_t* mask, int py) {
        typedef Lanes<8> H;
        return H::any(H::load(mask + at(0, py)) | H::load(mask + at(8, py)));
    }
    template <class Active, class Step>
    static void steps(const TileSplat& s, Active active, Step step) {
        V::vf centre[2], row_offset;
        V::vi upper;  // the lanes of the pair's first row
        for (int i = 0; i < 16; ++i) {
            centre[0][i] = float(i % 8) + 0.5f;
            centre[1][i] = float(8 + i % 8) + 0.5f;
            row_offset[i] = float(i / 8) + 0.5f;  // py + 1.5 == (py + 1) + 0.5 exactly
            upper[i] = i < 8 ? -1 : 0;
        }
        const V::vi both = V::splat_i(-1);
        for (int h = s.col0 / 8; h <= s.col1 / 8; ++h)
            for (int py = s.row0; py <= s.row1; py += 2) {
                const bool second = py < s.row1;
                if (!active(py) && !(second && active(py + 1))) continue;
                const V::vf dy = s.y - (float(py) + row_offset);
                step(at(8 * h, py), centre[h], dy, second ? both : upper);
            }
    }
};

// Compositing of a tile with the steps of Layout (RowSteps or PairSteps).
template <class Layout>
struct Raster {
    typedef typename Layout::V V;
    static constexpr int kSize = Layout::kSize;

    // Front-to-back compositing of one tile. Writes rgb/alpha/depth for the tile's pixels
    // and the per-pixel final transmittance and contributor count for the backward pass;
    // lanes[0] = pixel lanes evaluated, lanes[1] = those that composited a sample.
    static void composite_forward(const std::vector<TileSplat>& G, const TileFrame& f,
                                  const float* background, float* rgb, float* alpha, float* depth,
                                  float* T_final, int32_t* last_out, int64_t* lanes) {
        alignas(64) float T[kSize], cr[kSize], cg[kSize], cb[kSize], cz[kSize];
        alignas(64) int32_t live[kSize], last[kSize];
        std::fill_n(T, kSize, 1.0f);
        for (float* c : {cr, cg, cb, cz}) std::fill_n(c, kSize, 0.0f);
        std::fill_n(last, kSize, 0);
        std::fill_n(live, kSize, 0);  // padding and pixels outside the image stay 0
        for (int py = 0; py < kTile && f.oy + py < f.height; ++py)
            for (int px = 0; px < kTile && f.ox + px < f.width; ++px) live[Layout::at(px, py)] = -1;
        const typename V::ForwardState S{T, cr, cg, cb, cz, last, live};
        bool row_live[kTile];
        typename V::vi used{};
        int64_t steps = 0;
        const int64_t n = int64_t(G.size());
        for (int64_t j = 0; j < n; ++j) {
            if (j % kLiveCheck == 0) {
                bool tile_live = false;
                for (int py = 0; py < kTile; ++py) {
                    row_live[py] = Layout::row_any(live, py);
                    tile_live |= row_live[py];
                }
                if (!tile_live) break;
            }
            const TileSplat& s = G[j];
            const typename V::vi jj = V::splat_i(int32_t(j + 1));
            Layout::steps(
                s, [&](int py) { return row_live[py]; },
                [&](int p, typename V::vf centre, auto dy, typename V::vi valid) {
                    used += V::forward_step(S, s, p, centre, dy, jj, valid);
                    ++steps;
                });
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

    // Back-to-front pass over one tile: transmittance is recovered by dividing out each
    // alpha, and the gradient of everything behind a sample is carried as one scalar per
    // pixel. Writes the kEntryGrad floats of the tile's j-th entry at
    // entry_grad + slot[j] * kEntryGrad.
    static void composite_backward(const std::vector<TileSplat>& G, const TileFrame& f,
                                   const float* background, const float* g_rgb,
                                   const float* g_alpha, const float* g_depth, const float* T_final,
                                   const int32_t* last_in, const int64_t* slot, float* entry_grad) {
        alignas(64) float T[kSize], behind[kSize], gr[kSize], gg[kSize], gb[kSize], gz[kSize];
        alignas(64) int32_t last[kSize];
        std::fill_n(T, kSize, 1.0f);
        for (float* c : {behind, gr, gg, gb, gz}) std::fill_n(c, kSize, 0.0f);
        std::fill_n(last, kSize, 0);  // no sample is drawn at padding or outside the image
        int row_last[kTile] = {0};
        int tile_last = 0;
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
                row_last[py] = std::max(row_last[py], last[p]);
            }
            tile_last = std::max(tile_last, row_last[py]);
        }

        const int64_t n = int64_t(G.size());
        const int64_t n_used = std::min<int64_t>(n, tile_last);
        for (int64_t j = n_used; j < n; ++j)
            std::fill_n(entry_grad + slot[j] * kEntryGrad, kEntryGrad, 0.0f);
        const typename V::BackwardState S{T, behind, gr, gg, gb, gz, last};
        for (int64_t j = n_used - 1; j >= 0; --j) {
            const TileSplat& s = G[j];
            const typename V::vi jj = V::splat_i(int32_t(j));
            typename V::Moments M;
            Layout::steps(
                s, [&](int py) { return row_last[py] > j; },
                [&](int p, typename V::vf centre, auto dy, typename V::vi valid) {
                    V::backward_step(S, M, s, p, centre, dy, jj, valid);
                });
            float m[kEntryGrad] = {0};
            M.add_to(m);
            float* e = entry_grad + slot[j] * kEntryGrad;
            e[0] = -(s.ca * m[0] + s.cb * m[1]);  // dp/dmean_x = -(ca dx + cb dy)
            e[1] = -(s.cb * m[0] + s.cc * m[1]);
            e[2] = -0.5f * m[2];
            e[3] = -m[3];
            e[4] = -0.5f * m[4];
            std::copy(m + 5, m + kEntryGrad, e + 5);
        }
    }
};
