// `Raster<Wide>`, compositing with vectors of up to Wide pixels. No include guard: dispatch.hpp includes
// this file once per instruction set, each time inside its own namespace and
// `#pragma GCC target` region, so that every function of the template, helpers included,
// is compiled for that instruction set (a target attribute on an outer function alone lets
// GCC lower the wide vector compares of the helpers to scalar code before inlining them).
// Include raster.hpp first.

// One L-pixel step of the compositing loops (L divides the tile width: a tile row is
// kTile / L chunks).
template <int L>
struct Lanes {
    static_assert(kTile % L == 0, "a vector must not straddle tile rows");
    static constexpr int kChunks = kTile / L;
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

    static Falloff falloff(const TileSplat& s, vf px_centre, float dy) {
        Falloff f;
        f.dx = s.x - px_centre;
        f.power = -0.5f * (s.ca * f.dx * f.dx + s.cc * dy * dy) - s.cb * f.dx * dy;
        f.vis = falloff_exp(f.power);
        const vf t = s.op * f.vis;
        f.a = t < kAlphaMax ? t : splat(kAlphaMax);
        f.ok = (f.power <= 0.0f) & (f.a >= kAlphaMin);
        return f;
    }

    static vf lane_centres(int chunk) {
        vf c;
        for (int i = 0; i < L; ++i) c[i] = float(chunk * L + i) + 0.5f;
        return c;
    }

    // The tile's per-pixel state, rows of kTile pixels.
    struct ForwardState {
        float *T, *cr, *cg, *cb, *cz;
        int32_t *last, *live;
    };

    // Composites sample j (1-based count jj) of Gaussian s into the L pixels at p; returns
    // the lanes that composited it (-1) for the benchmark's lane counts.
    static vi forward_step(const ForwardState& S, const TileSplat& s, int p, vf centre,
                             float dy, vi jj) {
        const Falloff fo = falloff(s, centre, dy);
        const vi lv = load(S.live + p);
        const vf Tp = load(S.T + p);
        const vi ok = fo.ok & lv;
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
            const vf* v[kEntryGrad] = {&m_x, &m_y, &m_xx, &m_xy, &m_yy,
                                       &d_op, &d_r, &d_g, &d_b, &d_z};
            for (int c = 0; c < kEntryGrad; ++c) sums[c] += lane_sum(*v[c]);
        }
    };

    // Un-composites sample j (index jj) of Gaussian s at the L pixels at p, back to front.
    static void backward_step(const BackwardState& S, Moments& M, const TileSplat& s, int p,
                              vf centre, float dy, vi jj) {
        const Falloff fo = falloff(s, centre, dy);
        const vi ok = fo.ok & (jj < load(S.last + p));
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

// Compositing of a tile, 8 pixels a step; with Wide = 16, a row the Gaussian covers in both
// halves takes one 16-pixel step instead of two (AVX-512: no lane is evaluated that the
// 8-pixel path would not evaluate, in fewer instructions).
template <int Wide>
struct Raster {
    typedef Lanes<8> N;
    typedef Lanes<Wide> W;
    static constexpr bool kHasWide = Wide == kTile;

    static bool wide_row(const TileSplat& s) { return kHasWide && s.col0 < 8 && s.col1 >= 8; }

    // Front-to-back compositing of one tile. Writes rgb/alpha/depth for the tile's pixels
    // and the per-pixel final transmittance and contributor count for the backward pass;
    // lanes[0] = pixel lanes evaluated, lanes[1] = those that composited a sample.
    static void composite_forward(const std::vector<TileSplat>& G, const TileFrame& f,
                                  const float* background, float* rgb, float* alpha,
                                  float* depth, float* T_final, int32_t* last_out,
                                  int64_t* lanes) {
        alignas(64) float T[kTilePixels], cr[kTilePixels], cg[kTilePixels], cb[kTilePixels],
            cz[kTilePixels];
        alignas(64) int32_t live[kTilePixels], last[kTilePixels];
        const typename N::ForwardState SN{T, cr, cg, cb, cz, last, live};
        const typename W::ForwardState SW{T, cr, cg, cb, cz, last, live};
        bool row_live[kTile];
        for (int py = 0; py < kTile; ++py)
            for (int px = 0; px < kTile; ++px) {
                const int p = py * kTile + px;
                T[p] = 1.0f;
                cr[p] = cg[p] = cb[p] = cz[p] = 0.0f;
                last[p] = 0;
                live[p] = f.ox + px < f.width && f.oy + py < f.height ? -1 : 0;
            }
        const typename N::vf centre[2] = {N::lane_centres(0), N::lane_centres(1)};
        const typename W::vf centre_wide = W::lane_centres(0);
        typename N::vi used{};
        typename W::vi used_wide{};
        int64_t steps = 0, wide_steps = 0;
        const int64_t n = int64_t(G.size());
        for (int64_t j = 0; j < n; ++j) {
            if (j % kLiveCheck == 0) {
                bool tile_live = false;
                for (int py = 0; py < kTile; ++py) {
                    const int p = py * kTile;
                    row_live[py] = N::any(N::load(live + p) | N::load(live + p + 8));
                    tile_live |= row_live[py];
                }
                if (!tile_live) break;
            }
            const TileSplat& s = G[j];
            const bool wide = wide_row(s);
            for (int py = s.row0; py <= s.row1; ++py) {
                if (!row_live[py]) continue;
                const float dy = s.y - (float(py) + 0.5f);
                if (wide) {
                    used_wide += W::forward_step(SW, s, py * kTile, centre_wide, dy,
                                                 W::splat_i(j + 1));
                    ++wide_steps;
                    continue;
                }
                for (int h = s.col0 / 8; h <= s.col1 / 8; ++h, ++steps)
                    used += N::forward_step(SN, s, py * kTile + h * 8, centre[h], dy,
                                            N::splat_i(j + 1));
            }
        }

        for (int py = 0; py < kTile && f.oy + py < f.height; ++py)
            for (int px = 0; px < kTile && f.ox + px < f.width; ++px) {
                const int p = py * kTile + px;
                const int64_t o = int64_t(f.oy + py) * f.width + (f.ox + px);
                rgb[3 * o] = cr[p] + T[p] * background[0];
                rgb[3 * o + 1] = cg[p] + T[p] * background[1];
                rgb[3 * o + 2] = cb[p] + T[p] * background[2];
                alpha[o] = 1.0f - T[p];
                depth[o] = cz[p];
                T_final[o] = T[p];
                last_out[o] = last[p];
            }
        lanes[0] = 8 * steps + Wide * wide_steps;
        lanes[1] = N::count(used) + W::count(used_wide);
    }

    // Back-to-front pass over one tile: transmittance is recovered by dividing out each
    // alpha, and the gradient of everything behind a sample is carried as one scalar per
    // pixel. Writes the kEntryGrad floats of the tile's j-th entry at
    // entry_grad + slot[j] * kEntryGrad.
    static void composite_backward(const std::vector<TileSplat>& G, const TileFrame& f,
                                   const float* background, const float* g_rgb,
                                   const float* g_alpha, const float* g_depth,
                                   const float* T_final, const int32_t* last_in,
                                   const int64_t* slot, float* entry_grad) {
        alignas(64) float T[kTilePixels], behind[kTilePixels], gr[kTilePixels],
            gg[kTilePixels], gb[kTilePixels], gz[kTilePixels];
        alignas(64) int32_t last[kTilePixels];
        const typename N::BackwardState SN{T, behind, gr, gg, gb, gz, last};
        const typename W::BackwardState SW{T, behind, gr, gg, gb, gz, last};
        int row_last[kTile];
        int tile_last = 0;
        for (int py = 0; py < kTile; ++py) {
            row_last[py] = 0;
            for (int px = 0; px < kTile; ++px) {
                const int p = py * kTile + px;
                T[p] = 1.0f;
                behind[p] = gr[p] = gg[p] = gb[p] = gz[p] = 0.0f;
                last[p] = 0;
                if (f.ox + px >= f.width || f.oy + py >= f.height) continue;
                const int64_t o = int64_t(f.oy + py) * f.width + (f.ox + px);
                gr[p] = g_rgb[3 * o];
                gg[p] = g_rgb[3 * o + 1];
                gb[p] = g_rgb[3 * o + 2];
                gz[p] = g_depth ? g_depth[o] : 0.0f;
                const float ga = g_alpha ? g_alpha[o] : 0.0f;
                T[p] = T_final[o];
                // rgb = ... + T bg and alpha = 1 - T: dL/dT_final, times T_final.
                behind[p] = (gr[p] * background[0] + gg[p] * background[1] +
                             gb[p] * background[2] - ga) *
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
        const typename N::vf centre[2] = {N::lane_centres(0), N::lane_centres(1)};
        const typename W::vf centre_wide = W::lane_centres(0);
        for (int64_t j = n_used - 1; j >= 0; --j) {
            const TileSplat& s = G[j];
            const bool wide = wide_row(s);
            typename N::Moments MN;
            typename W::Moments MW;
            for (int py = s.row0; py <= s.row1; ++py) {
                if (row_last[py] <= j) continue;
                const float dy = s.y - (float(py) + 0.5f);
                if (wide) {
                    W::backward_step(SW, MW, s, py * kTile, centre_wide, dy, W::splat_i(j));
                    continue;
                }
                for (int h = s.col0 / 8; h <= s.col1 / 8; ++h)
                    N::backward_step(SN, MN, s, py * kTile + h * 8, centre[h], dy,
                                     N::splat_i(j));
            }
            float m[kEntryGrad] = {0};
            if (wide)
                MW.add_to(m);
            else
                MN.add_to(m);
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
