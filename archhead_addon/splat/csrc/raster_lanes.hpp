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

    // A step's record at out, returning the end: vis (0 off the lanes of mask m). AVX-512:
    // those lanes only, after m (the record of a 3 lane step: 4 values, not 16); writes up to
    // L + 1 values.
    static float* pack(float* out, uint32_t m, vf vis) {
#ifdef __x86_64__
        if constexpr (L == 16) {
            std::memcpy(out, &m, sizeof m);
            store(out + 1, (vf)_mm512_maskz_compress_ps(__mmask16(m), (__m512)vis));
            return out + 1 + __builtin_popcount(m);
        }
#endif
        store(out, vis);
        return out + L;
    }
    // The vis of the record at rec (reads up to L + 1 values), returning the record's end.
    static const float* unpack(const float* rec, vf& vis) {
#ifdef __x86_64__
        if constexpr (L == 16) {
            uint32_t m;
            std::memcpy(&m, rec, sizeof m);
            vis = (vf)_mm512_maskz_expand_ps(__mmask16(m), (__m512)load(rec + 1));
            return rec + 1 + __builtin_popcount(m);
        }
#endif
        vis = load(rec);
        return rec + L;
    }
    static vf sqrt(vf x) {
#ifdef __x86_64__
        if constexpr (L == 4) return (vf)_mm_sqrt_ps((__m128)x);
        if constexpr (L == 8) return (vf)_mm256_sqrt_ps((__m256)x);
        if constexpr (L == 16) return (vf)_mm512_mask_sqrt_ps((__m512)x, 0xffff, (__m512)x);
#endif
        for (int i = 0; i < L; ++i) x[i] = std::sqrt(x[i]);
        return x;
    }
    // a > b ? a : b and a < b ? a : b (b where either is NaN), as the max / min instructions
    // (GCC's generic code for the selects takes a compare and a blend).
    static vf max(vf a, vf b) {
#ifdef __x86_64__
        if constexpr (L == 4) return (vf)_mm_max_ps((__m128)a, (__m128)b);
        if constexpr (L == 8) return (vf)_mm256_max_ps((__m256)a, (__m256)b);
        if constexpr (L == 16)  // masked: the plain form's undefined source draws a warning
            return (vf)_mm512_mask_max_ps((__m512)a, 0xffff, (__m512)a, (__m512)b);
#endif
        return a > b ? a : b;
    }
    static vf min(vf a, vf b) {
#ifdef __x86_64__
        if constexpr (L == 4) return (vf)_mm_min_ps((__m128)a, (__m128)b);
        if constexpr (L == 8) return (vf)_mm256_min_ps((__m256)a, (__m256)b);
        if constexpr (L == 16)
            return (vf)_mm512_mask_min_ps((__m512)a, 0xffff, (__m512)a, (__m512)b);
#endif
        return a < b ? a : b;
    }

    static vf vec(vf x) { return x; }
    static vf vec(float x) { return splat(x); }
    // a b + c, fused (one rounding) on the AVX2 and AVX-512 paths. SSE2 has no FMA: the
    // baseline path rounds twice, and its images differ from theirs by round-off.
    template <class B, class A>
    static vf fma(vf a, B b, A c) {
#ifdef __x86_64__
        if constexpr (L == 8) return (vf)_mm256_fmadd_ps((__m256)a, (__m256)vec(b), (__m256)vec(c));
        if constexpr (L == 16)
            return (vf)_mm512_fmadd_ps((__m512)a, (__m512)vec(b), (__m512)vec(c));
#endif
        return a * b + c;
    }

    // exp for the Gaussian falloff (Cephes expf polynomial, about 1 ulp, exp(0) == 1
    // exactly). NaN and large |x| map to the clamp bounds.
    static vf falloff_exp(vf x) {
        x = min(max(x, splat(-87.0f)), splat(88.0f));
        const vf n = fma(x, 1.44269504088896341f, 12582912.0f) - 12582912.0f;  // round
        vf r = fma(n, -0.693359375f, x);
        r = fma(n, 2.12194440e-4f, r);
        vf p = splat(1.9875691500e-4f);
        p = fma(p, r, 1.3981999507e-3f);
        p = fma(p, r, 8.3334519073e-3f);
        p = fma(p, r, 4.1665795894e-2f);
        p = fma(p, r, 1.6666665459e-1f);
        p = fma(p, r, 5.0000001201e-1f);
        const vf y = fma(p, r * r, r) + 1.0f;
        const vi bits = (__builtin_convertvector(n, vi) + 127) << 23;
        return y * (vf)bits;
    }

    // alpha of one Gaussian at L pixel centres.
    struct Falloff {
        vf dx, power, vis, a;
        vi ok;  // power <= 0 and a >= 1/255 (also false for NaN)
    };

    // dy: a float (one row) or a vector (a row per lane).
    template <class DY>
    static Falloff falloff(const TileSplat& s, vf px_centre, DY dy) {
        Falloff f;
        f.dx = s.x - px_centre;
        f.power = fma(fma(s.ca * f.dx, f.dx, s.cc * dy * dy), -0.5f, -(s.cb * f.dx * dy));
        f.vis = falloff_exp(f.power);
        const vf t = s.op * f.vis;
        f.a = min(t, splat(kAlphaMax));
        f.ok = (f.power <= 0.0f) & (f.a >= kAlphaMin);
        return f;
    }

    // Pixel centres of columns (or rows) first .. first + L - 1 (exact: small integers and
    // halves).
    static vf lane_centres(int first) {
        vf c;
        for (int i = 0; i < L; ++i) c[i] = float(first + i) + 0.5f;
        return c;
    }

    // For each row py of a tile of `rows` rows at (gx, gy) from its grid origin, the pixel
    // centres [lo[py], hi[py]] (tile coordinates; lo > hi: none) where s may pass the alpha
    // test (Span).
    template <int rows>
    static void row_spans(const TileSplat& s, int gx, int gy, float* lo, float* hi) {
        constexpr float inf = std::numeric_limits<float>::infinity();
        const Span& e = s.span;
        for (int r = 0; r < rows; r += L) {
            const vf dy = s.y - lane_centres(gy + r);
            const vf c = (s.x - float(gx)) + e.slope * dy, w2 = (e.q - e.g * dy * dy) * e.inv_ca;
            const vf w = sqrt(max(w2, splat(0.0f))) + kSpanMargin;
            const vf l = c - w, h = c + w;  // NaN only as inf - inf: the whole row
            store(lo + r, w2 < 0.0f ? splat(inf) : (l == l ? l : splat(-inf)));
            store(hi + r, w2 < 0.0f ? splat(-inf) : (h == h ? h : splat(inf)));
        }
    }

    // The tile's per-pixel state, rows of kTile pixels.
    struct ForwardState {
        float *T, *cr, *cg, *cb, *cz;
        int32_t* live;
    };

    // Composites Gaussian s into the L pixels at p, those of them in `valid`; returns the
    // lanes that composited it (bit i: lane i), with their falloff in vis (0 in the other
    // lanes).
    template <class DY>
    static uint32_t forward_step(const ForwardState& S, const TileSplat& s, int p, vf centre, DY dy,
                                 vi valid, vf& vis) {
        const Falloff fo = falloff(s, centre, dy);
#ifdef __x86_64__
        if constexpr (L == 16) {  // the same operations on mask registers, stores masked
            const __m512 a = (__m512)fo.a, Tp = (__m512)load(S.T + p);
            const __m512i lv = (__m512i)load(S.live + p);
            __mmask16 ok = _mm512_test_epi32_mask((__m512i)valid, lv);
            ok = _mm512_mask_cmp_ps_mask(ok, (__m512)fo.power, _mm512_setzero_ps(), _CMP_LE_OQ);
            ok = _mm512_mask_cmp_ps_mask(ok, a, _mm512_set1_ps(kAlphaMin), _CMP_GE_OQ);
            const __m512 nT = _mm512_mul_ps(Tp, _mm512_sub_ps(_mm512_set1_ps(1.0f), a));
            const __mmask16 stop =
                _mm512_mask_cmp_ps_mask(ok, nT, _mm512_set1_ps(kTransmittanceMin), _CMP_LT_OQ);
            const __mmask16 use = _kandn_mask16(stop, ok);
            const vf w = (vf)_mm512_maskz_mul_ps(use, a, Tp);
            store(S.cr + p, fma(w, s.r, load(S.cr + p)));
            store(S.cg + p, fma(w, s.g, load(S.cg + p)));
            store(S.cb + p, fma(w, s.b, load(S.cb + p)));
            store(S.cz + p, fma(w, s.z, load(S.cz + p)));
            _mm512_mask_storeu_ps(S.T + p, use, nT);
            _mm512_mask_storeu_epi32(S.live + p, stop, _mm512_setzero_si512());
            vis = (vf)_mm512_maskz_mov_ps(use, (__m512)fo.vis);
            return use;
        }
#endif
        const vi lv = load(S.live + p);
        const vf Tp = load(S.T + p);
        const vi ok = fo.ok & lv & valid;
        const vf nT = Tp * (1.0f - fo.a);
        const vi stop = ok & (nT < kTransmittanceMin);
        const vi use = ok & ~stop;
        const vf w = use ? fo.a * Tp : splat(0.0f);
        store(S.cr + p, fma(w, s.r, load(S.cr + p)));
        store(S.cg + p, fma(w, s.g, load(S.cg + p)));
        store(S.cb + p, fma(w, s.b, load(S.cb + p)));
        store(S.cz + p, fma(w, s.z, load(S.cz + p)));
        store(S.T + p, use ? nT : Tp);
        store(S.live + p, lv & ~stop);
        vis = use ? fo.vis : splat(0.0f);
        return bits(use);
    }

    struct BackwardState {
        float *T, *behind;
        const float *gr, *gg, *gb, *gz;
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

    // Un-composites Gaussian s at the L pixels at p, back to front, from the falloff vis
    // that the forward recorded (0 where it composited nothing: the same lanes).
    template <class DY>
    static void backward_step(const BackwardState& S, Moments& M, const TileSplat& s, int p,
                              vf centre, DY dy, vf vis) {
        const vi ok = vis > 0.0f;
        const vf t = s.op * vis;
        const vf a = min(t, splat(kAlphaMax));  // the forward's alpha, 0 off ok
        const vf dx = s.x - centre;
        const vf inv_one_minus = 1.0f / (1.0f - a);
        const vf Tj = load(S.T + p) * inv_one_minus;
        const vf pr = load(S.gr + p), pg = load(S.gg + p), pb = load(S.gb + p);
        const vf pz = load(S.gz + p);
        const vf gp = fma(pz, s.z, fma(pb, s.b, fma(pg, s.g, pr * s.r)));
        const vf w = a * Tj;
        const vf beh = load(S.behind + p);
        const vf d_alpha = fma(Tj, gp, -(beh * inv_one_minus));
        store(S.behind + p, fma(w, gp, beh));
        store(S.T + p, Tj);
        M.d_r = fma(pr, w, M.d_r);
        M.d_g = fma(pg, w, M.d_g);
        M.d_b = fma(pb, w, M.d_b);
        M.d_z = fma(pz, w, M.d_z);
        // alpha = min(0.99, op * vis): no gradient through the clamp
        const vf da = (t <= kAlphaMax) & ok ? d_alpha : splat(0.0f);
        M.d_op = fma(da, vis, M.d_op);
        const vf d_pow = da * a;
        const vf wx = d_pow * dx, wy = d_pow * dy;
        M.m_x += wx;
        M.m_y += wy;
        M.m_xx = fma(wx, dx, M.m_xx);
        M.m_xy = fma(wx, dy, M.m_xy);
        M.m_yy = fma(wy, dy, M.m_yy);
    }
};

// The step layout: a tile of T x T pixels stored block by block, C columns x (T + R - 1) rows each
// (R - 1 rows of padding), so that R consecutive rows of a block are C R contiguous values
// and one step of L = C R lanes covers C columns x R rows starting at any row. A Gaussian
// takes the steps of the blocks its box reaches in bands of R rows from its first row:
// step k = band kBlocks + b (bit k of a 64-bit step mask). `steps` runs the forward's (those
// the Gaussian's ellipse reaches, with a live pixel) as step(k, p, centre, dy, valid), and
// `masked_steps` those of a mask in the same order as step(p, centre, dy, valid): the
// backward's, where the forward composited a sample (exactly the lanes it un-composites).
// AVX-512: 4 x 4 (about 15 % fewer steps on faces than 8 x 2, as small Gaussians leave
// less of a narrower block unused); AVX2: 4 x 2; baseline: 4 x 1, as SSE2 has no 8-lane
// compares and GCC would split them into scalar code.
template <int C, int R, int T>
struct BlockSteps {
    typedef Lanes<C * R> V;
    static constexpr int kTile = T;
    static constexpr int kRows = kTile + R - 1;
    static constexpr int kBlock = C * kRows;
    static constexpr int kBlocks = kTile / C;
    static constexpr int kColumns = C;
    static constexpr int kSize = kBlocks * kBlock;
    static constexpr int kGroups = kBlocks;  // live-row masks (bit py), one per block
    static_assert(kBlocks * ((kTile + R - 1) / R) <= 64, "step masks have 64 bits");
    static int at(int px, int py) { return (px / C) * kBlock + py * C + px % C; }
    // Bit py of rows[b]: a pixel of row py of block b is live. From the lane bits of a
    // block's first kTile rows (bit C py + x), folding each row's C bits into one.
    static void live_rows(const int32_t* live, uint32_t* rows) {
        if constexpr (C != 4) {
            for (int b = 0; b < kBlocks; ++b) {
                rows[b] = 0;
                for (int py = 0; py < kTile; ++py)
                    rows[b] |= uint32_t(Lanes<C>::any(Lanes<C>::load(live + at(C * b, py)))) << py;
            }
            return;
        }
        static_assert(kTile % 16 == 0 && kTile <= 32, "16 rows at a time, 32 bits");
        for (int b = 0; b < kBlocks; ++b) {
            rows[b] = 0;
            for (int g = 0; g < kTile / 16; ++g) {  // 16 rows (64 lanes) at a time
                uint64_t m = 0;
                for (int i = 0; i < 64 / V::kWidth; ++i)
                    m |= uint64_t(V::bits(V::load(live + at(C * b, 16 * g) + V::kWidth * i)))
                         << (V::kWidth * i);
                m = (m | m >> 1 | m >> 2 | m >> 3) & 0x1111111111111111u;  // row py: bit 4 py
                m = (m | m >> 3) & 0x0303030303030303u;
                m = (m | m >> 6) & 0x000f000f000f000fu;
                m = (m | m >> 12) & 0x000000ff000000ffu;
                rows[b] |= uint32_t((m | m >> 24) & 0xffffu) << (16 * g);
            }
        }
    }
    template <class Step>
    [[gnu::always_inline]] static void steps(const TileSplat& s, const TileFrame& f,
                                             const uint32_t* live, Step step) {
        alignas(64) float lo[kTile], hi[kTile];
        V::template row_spans<kTile>(s, grid_x(f), grid_y(f), lo, hi);
        for (int band = 0, py = s.row0; py <= s.row1; ++band, py += R) {
            const int rows = std::min(R, s.row1 - py + 1);
            float l = lo[py], h = hi[py];
            for (int r = 1; r < rows; ++r) l = std::min(l, lo[py + r]), h = std::max(h, hi[py + r]);
            // the blocks of the box whose centres C b + 0.5 .. C b + C - 0.5 meet [l, h]
            const float first = (l - (C - 0.5f)) / C, last = (h - 0.5f) / C;
            int b0 = s.col0 / C, b1 = s.col1 / C;
            if (first > b0) b0 = first > b1 ? b1 + 1 : int(first) + (int(first) < first);  // ceil
            if (last < b1) b1 = last < b0 ? b0 - 1 : int(last);  // floor: 0 <= last < b1 here
            const uint32_t band_rows = ((1u << rows) - 1) << py;
            const auto dy = band_dy(s, grid_y(f) + py);
            const typename V::vi valid = band_valid(s, py);
            for (int b = b0; b <= b1; ++b)
                if (live[b] & band_rows)
                    step(band * kBlocks + b, at(C * b, py), block_centres(grid_x(f) + C * b), dy,
                         valid);
        }
    }
    template <class Step>
    [[gnu::always_inline]] static void masked_steps(const TileSplat& s, const TileFrame& f,
                                                    uint64_t mask, Step step) {
        for (; mask; mask &= mask - 1) step_at(s, f, __builtin_ctzll(mask), step);
    }
    // Step k of s as step(p, centre, dy, valid); dy a float for one row.
    template <class Step>
    [[gnu::always_inline]] static void step_at(const TileSplat& s, const TileFrame& f, int k,
                                               Step&& step) {
        const int b = unsigned(k) % kBlocks, py = s.row0 + R * int(unsigned(k) / kBlocks);
        step(at(C * b, py), block_centres(grid_x(f) + C * b), band_dy(s, grid_y(f) + py),
             band_valid(s, py));
    }
    // The tile's origin from its grid origin (TileFrame): 0 where the tiles are the grid's.
    static int grid_x(const TileFrame& f) { return kTile == kMaxTile ? 0 : f.grid_x(); }
    static int grid_y(const TileFrame& f) { return kTile == kMaxTile ? 0 : f.grid_y(); }
    // The pixel centres' columns of a block from column x (from the grid origin), lane by lane.
    static typename V::vf block_centres(int x) {
        typename V::vf centre;
        for (int l = 0; l < C * R; ++l) centre[l] = float(l % C) + 0.5f;
        return centre + float(x);
    }
    // s.y minus the pixel centres' rows of the band from row py (from the grid origin), lane
    // by lane (a float when the band is one row).
    static auto band_dy(const TileSplat& s, int py) {
        if constexpr (R == 1) {
            return s.y - (float(py) + 0.5f);
        } else {
            typename V::vf row_offset;
            for (int l = 0; l < C * R; ++l)
                row_offset[l] = float(l / C) + 0.5f;  // py + (r + 0.5) == (py + r) + 0.5 exactly
            return s.y - (float(py) + row_offset);
        }
    }
    // Which lanes' rows of the band from tile row py are in s's box.
    static typename V::vi band_valid(const TileSplat& s, int py) {
        typename V::vi row;
        for (int l = 0; l < C * R; ++l) row[l] = l / C;
        return R == 1 ? V::splat_i(-1) : row <= s.row1 - py;
    }
};

// Compositing of a tile with the steps of Layout (a BlockSteps).
template <class Layout>
struct Raster {
    typedef typename Layout::V V;
    static constexpr int kSize = Layout::kSize, kTile = Layout::kTile;

    // Front-to-back compositing of one tile. Writes rgb/alpha/depth for the tile's pixels
    // and, for the backward pass, the per-pixel final transmittance, each Gaussian's mask of
    // the steps that composited a sample (step_mask[j], left as it is for Gaussians after
    // the tile turned opaque) and, appended to records (unless null), the falloff of each
    // such step's lanes (forward_step's vis); lanes[0] = pixel lanes evaluated, lanes[1] = those
    // that composited a sample.
    static void composite_forward(const TileSplat* G, int64_t n, const TileFrame& f,
                                  const float* background, float* rgb, float* alpha, float* depth,
                                  float* T_final, uint64_t* step_mask, StepRecords* records,
                                  int64_t* record_start, int64_t* lanes) {
        alignas(64) float T[kSize], cr[kSize], cg[kSize], cb[kSize], cz[kSize];
        alignas(64) int32_t live[kSize];
        std::fill_n(T, kSize, 1.0f);
        for (float* c : {cr, cg, cb, cz}) std::fill_n(c, kSize, 0.0f);
        std::fill_n(live, kSize, 0);  // padding and pixels outside the image stay 0
        for (int py = 0; py < kTile && f.oy + py < f.height; ++py)
            for (int px = 0; px < kTile && f.ox + px < f.width; ++px) live[Layout::at(px, py)] = -1;
        const typename V::ForwardState S{T, cr, cg, cb, cz, live};
        uint32_t live_rows[Layout::kGroups] = {};
        int64_t used = 0;  // lanes that composited a sample
        int64_t steps = 0;
        for (int64_t j = 0; j < n; ++j) {
            if (j % kLiveCheck == 0) {
                Layout::live_rows(live, live_rows);
                uint32_t tile_live = 0;
                for (uint32_t rows : live_rows) tile_live |= rows;
                if (!tile_live) break;
            }
            const TileSplat& s = G[j];
            uint64_t mask = 0;
            float* out = nullptr;  // where the entry's records go, if kept
            if (records) {
                out = records->reserve(64 * (V::kWidth + 1));  // 64 steps at most
                record_start[j] = out - records->data.data();
            }
            Layout::steps(s, f, live_rows,
                          [&](int k, int p, typename V::vf centre, auto dy, typename V::vi valid) {
                              typename V::vf vis;
                              const uint32_t use = V::forward_step(S, s, p, centre, dy, valid, vis);
                              used += __builtin_popcount(use);
                              ++steps;
                              if (use) {
                                  mask |= uint64_t(1) << k;
                                  if (out) out = V::pack(out, use, vis);
                              }
                          });
            if (records) records->size = out - records->data.data();
            step_mask[j] = mask;
        }

        typedef Lanes<4> H;
        tile_pixels(
            f,
            [&](int p, int64_t o) {
                const typename H::vf t = H::load(T + p);
                const typename H::vf r = H::load(cr + p) + t * background[0];
                const typename H::vf g = H::load(cg + p) + t * background[1];
                const typename H::vf b = H::load(cb + p) + t * background[2];
                H::store(alpha + o, 1.0f - t);
                H::store(depth + o, H::load(cz + p));
                H::store(T_final + o, t);
                float* out = rgb + 3 * o;
                for (int i = 0; i < 4; ++i)
                    out[3 * i] = r[i], out[3 * i + 1] = g[i], out[3 * i + 2] = b[i];
            },
            [&](int p, int64_t o) {
                rgb[3 * o] = cr[p] + T[p] * background[0];
                rgb[3 * o + 1] = cg[p] + T[p] * background[1];
                rgb[3 * o + 2] = cb[p] + T[p] * background[2];
                alpha[o] = 1.0f - T[p];
                depth[o] = cz[p];
                T_final[o] = T[p];
            });
        lanes[0] = V::kWidth * steps;
        lanes[1] = used;
    }

    // The tile's pixels inside the image, a block's row (4 contiguous pixels of the tile
    // state, 4 of the image row) at a time where the row holds one: chunk(p, o) for those,
    // pixel(p, o) for the rest; p in the tile state, o in the image.
    template <class Chunk, class Pixel>
    static void tile_pixels(const TileFrame& f, Chunk chunk, Pixel pixel) {
        static_assert(Layout::kColumns == 4, "block rows of 4 pixels");
        const int cols = std::min(kTile, f.width - f.ox);
        for (int py = 0; py < kTile && f.oy + py < f.height; ++py) {
            const int64_t row = int64_t(f.oy + py) * f.width + f.ox;
            int px = 0;
            for (; px + 4 <= cols; px += 4) chunk(Layout::at(px, py), row + px);
            for (; px < cols; ++px) pixel(Layout::at(px, py), row + px);
        }
    }

    // Back-to-front pass over one tile, over the steps in which the forward composited a
    // sample, from their records (the forward's, from `records` on): transmittance is
    // recovered by dividing out each alpha, and the gradient of everything behind a sample
    // is carried as one scalar per pixel. Writes the kEntryGrad floats of the tile's j-th
    // entry at entry_grad + slot[j] * kEntryGrad.
    static void composite_backward(const TileSplat* G, int64_t n, const TileFrame& f,
                                   const float* background, const float* g_rgb,
                                   const float* g_alpha, const float* g_depth, const float* T_final,
                                   const uint64_t* step_mask, const float* records,
                                   const int64_t* record_start, const int64_t* slot,
                                   float* entry_grad) {
        alignas(64) float T[kSize], behind[kSize], gr[kSize], gg[kSize], gb[kSize], gz[kSize];
        std::fill_n(T, kSize, 1.0f);
        for (float* c : {behind, gr, gg, gb, gz}) std::fill_n(c, kSize, 0.0f);
        typedef Lanes<4> H;
        tile_pixels(
            f,
            [&](int p, int64_t o) {
                typename H::vf r, g, b;
                for (int i = 0; i < 4; ++i)
                    r[i] = g_rgb[3 * (o + i)], g[i] = g_rgb[3 * (o + i) + 1],
                    b[i] = g_rgb[3 * (o + i) + 2];
                const typename H::vf ga = g_alpha ? H::load(g_alpha + o) : H::splat(0.0f);
                const typename H::vf t = H::load(T_final + o);
                H::store(gr + p, r);
                H::store(gg + p, g);
                H::store(gb + p, b);
                H::store(gz + p, g_depth ? H::load(g_depth + o) : H::splat(0.0f));
                H::store(T + p, t);
                // rgb = ... + T bg and alpha = 1 - T: dL/dT_final, times T_final.
                H::store(behind + p,
                         (r * background[0] + g * background[1] + b * background[2] - ga) * t);
            },
            [&](int p, int64_t o) {
                gr[p] = g_rgb[3 * o];
                gg[p] = g_rgb[3 * o + 1];
                gb[p] = g_rgb[3 * o + 2];
                gz[p] = g_depth ? g_depth[o] : 0.0f;
                const float ga = g_alpha ? g_alpha[o] : 0.0f;
                T[p] = T_final[o];
                behind[p] =
                    (gr[p] * background[0] + gg[p] * background[1] + gb[p] * background[2] - ga) *
                    T[p];
            });

        const typename V::BackwardState S{T, behind, gr, gg, gb, gz};
        for (int64_t j = n - 1; j >= 0; --j) {
            float* e = entry_grad + slot[j] * kEntryGrad;
            if (!step_mask[j]) {
                std::fill_n(e, kEntryGrad, 0.0f);
                continue;
            }
            const TileSplat& s = G[j];
            const float* rec = records + record_start[j];
            typename V::Moments M;
            Layout::masked_steps(s, f, step_mask[j],
                                 [&](int p, typename V::vf centre, auto dy, typename V::vi) {
                                     typename V::vf vis;
                                     rec = V::unpack(rec, vis);
                                     V::backward_step(S, M, s, p, centre, dy, vis);
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
