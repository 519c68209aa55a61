// Per-tile compositing, forward and backward. One thread owns a whole 16x16 tile and
// walks its Gaussians in depth order; for each Gaussian it updates the rows of the tile
// that the Gaussian's box covers, 8 pixels at a time with GCC vector extensions (explicit,
// so the code vectorises whatever the optimiser's heuristics; without AVX the compiler
// splits each 8-lane operation in two).
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <vector>

#include "binning.hpp"
#include "projection.hpp"

// The hot loops get an AVX2 clone picked at load time; the default clone keeps the
// library portable to any x86-64 (other architectures build the plain version).
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define AH_HOT __attribute__((target_clones("avx2", "default")))
#else
#define AH_HOT
#endif

namespace ah {

constexpr int kTilePixels = kTile * kTile;
constexpr int kLanes = 8;

typedef float vf __attribute__((vector_size(4 * kLanes)));
typedef int32_t vi __attribute__((vector_size(4 * kLanes)));

inline vf splat(float x) { return vf{} + x; }
inline vi splat_i(int32_t x) { return vi{} + x; }
inline vf load(const float* p) {
    vf v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
inline vi load(const int32_t* p) {
    vi v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
inline void store(float* p, vf v) { std::memcpy(p, &v, sizeof v); }
inline void store(int32_t* p, vi v) { std::memcpy(p, &v, sizeof v); }
inline float lane_sum(vf v) {
    float s = 0.0f;
    for (int i = 0; i < kLanes; ++i) s += v[i];
    return s;
}
inline bool any(vi m) {
    int32_t s = 0;
    for (int i = 0; i < kLanes; ++i) s |= m[i];
    return s != 0;
}

// exp for the Gaussian falloff (Cephes expf polynomial, about 1 ulp, exp(0) == 1 exactly).
// NaN and large |x| map to the clamp bounds.
inline vf falloff_exp(vf x) {
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

// A Gaussian as one tile reads it: 2D mean relative to the tile origin (small numbers keep
// the float32 offsets accurate), conic, opacity, colour, depth, and the rows and 8-pixel
// column halves of the tile its box covers.
struct TileSplat {
    float x, y, ca, cb, cc, op, r, g, b, z;
    int32_t row0, row1, half0, half1;
};

// Projected Gaussians in input order (SoA), as the rasteriser reads them.
struct Projected {
    std::vector<double> mean2d;  // 2 per Gaussian
    std::vector<float> conic;    // 3
    std::vector<float> opacity;
    std::vector<float> depth;
    std::vector<int32_t> bbox;  // 4: x0, x1, y0, y1 inclusive
};

inline void gather_tile(std::vector<TileSplat>& out, const Projected& P, const float* colors,
                        const int32_t* ids, int64_t n, int ox, int oy) {
    out.resize(n);
    for (int64_t j = 0; j < n; ++j) {
        const int32_t id = ids[j];
        TileSplat& s = out[j];
        s.x = float(P.mean2d[2 * id] - ox);
        s.y = float(P.mean2d[2 * id + 1] - oy);
        s.ca = P.conic[3 * id];
        s.cb = P.conic[3 * id + 1];
        s.cc = P.conic[3 * id + 2];
        s.op = P.opacity[id];
        s.r = colors[3 * id];
        s.g = colors[3 * id + 1];
        s.b = colors[3 * id + 2];
        s.z = P.depth[id];
        s.half0 = std::max(P.bbox[4 * id] - ox, 0) / kLanes;
        s.half1 = std::min(P.bbox[4 * id + 1] - ox, kTile - 1) / kLanes;
        s.row0 = std::max(P.bbox[4 * id + 2] - oy, 0);
        s.row1 = std::min(P.bbox[4 * id + 3] - oy, kTile - 1);
    }
}

// alpha of one Gaussian at 8 pixel centres; forward and backward share it so that their
// skip decisions agree bit for bit.
struct Falloff {
    vf dx, power, vis, a;
    vi ok;  // power <= 0 and a >= 1/255 (also false for NaN)
};

inline Falloff falloff(const TileSplat& s, vf px_centre, float dy) {
    Falloff f;
    f.dx = s.x - px_centre;
    f.power = -0.5f * (s.ca * f.dx * f.dx + s.cc * dy * dy) - s.cb * f.dx * dy;
    f.vis = falloff_exp(f.power);
    const vf t = s.op * f.vis;
    f.a = t < kAlphaMax ? t : splat(kAlphaMax);
    f.ok = (f.power <= 0.0f) & (f.a >= kAlphaMin);
    return f;
}

inline vf lane_centres(int half) {
    vf c;
    for (int i = 0; i < kLanes; ++i) c[i] = float(half * kLanes + i) + 0.5f;
    return c;
}

struct TileFrame {
    int ox, oy, width, height;  // tile origin in pixels, image size
};

constexpr int kLiveCheck = 16;  // Gaussians between checks for finished rows / tiles

// Front-to-back compositing of one tile. Writes rgb/alpha/depth for the tile's pixels and
// the per-pixel final transmittance and contributor count for the backward pass.
AH_HOT inline void composite_forward(const std::vector<TileSplat>& G, const TileFrame& f,
                                     const float* background, float* rgb, float* alpha,
                                     float* depth, float* T_final, int32_t* last_out) {
    alignas(64) float T[kTilePixels], cr[kTilePixels], cg[kTilePixels], cb[kTilePixels],
        cz[kTilePixels];
    alignas(64) int32_t live[kTilePixels], last[kTilePixels];
    bool row_live[kTile];
    for (int py = 0; py < kTile; ++py)
        for (int px = 0; px < kTile; ++px) {
            const int p = py * kTile + px;
            T[p] = 1.0f;
            cr[p] = cg[p] = cb[p] = cz[p] = 0.0f;
            last[p] = 0;
            live[p] = f.ox + px < f.width && f.oy + py < f.height ? -1 : 0;
        }
    const vf centre[2] = {lane_centres(0), lane_centres(1)};
    const int64_t n = int64_t(G.size());
    for (int64_t j = 0; j < n; ++j) {
        if (j % kLiveCheck == 0) {
            bool tile_live = false;
            for (int py = 0; py < kTile; ++py) {
                const int p = py * kTile;
                row_live[py] = any(load(live + p) | load(live + p + kLanes));
                tile_live |= row_live[py];
            }
            if (!tile_live) break;
        }
        const TileSplat& s = G[j];
        const vi jj = splat_i(int32_t(j + 1));
        for (int py = s.row0; py <= s.row1; ++py) {
            if (!row_live[py]) continue;
            const float dy = s.y - (float(py) + 0.5f);
            for (int h = s.half0; h <= s.half1; ++h) {
                const int p = py * kTile + h * kLanes;
                const Falloff fo = falloff(s, centre[h], dy);
                const vi lv = load(live + p);
                const vf Tp = load(T + p);
                const vi ok = fo.ok & lv;
                const vf nT = Tp * (1.0f - fo.a);
                const vi stop = ok & (nT < kTransmittanceMin);
                const vi use = ok & ~stop;
                const vf w = use ? fo.a * Tp : splat(0.0f);
                store(cr + p, load(cr + p) + w * s.r);
                store(cg + p, load(cg + p) + w * s.g);
                store(cb + p, load(cb + p) + w * s.b);
                store(cz + p, load(cz + p) + w * s.z);
                store(T + p, use ? nT : Tp);
                store(last + p, use ? jj : load(last + p));
                store(live + p, lv & ~stop);
            }
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
}

constexpr int kEntryGrad = 10;  // d mean2d (2), d conic (3), d opacity, d rgb (3), d depth

// Back-to-front pass over one tile: transmittance is recovered by dividing out each alpha,
// and the gradient of everything behind a sample is carried as one scalar per pixel.
// Writes the kEntryGrad floats of the tile's j-th entry at entry_grad + slot[j] * kEntryGrad.
AH_HOT inline void composite_backward(const std::vector<TileSplat>& G, const TileFrame& f,
                                      const float* background, const float* g_rgb,
                                      const float* g_alpha, const float* g_depth,
                                      const float* T_final, const int32_t* last_in,
                                      const int64_t* slot, float* entry_grad) {
    alignas(64) float T[kTilePixels], behind[kTilePixels], gr[kTilePixels], gg[kTilePixels],
        gb[kTilePixels], gz[kTilePixels];
    alignas(64) int32_t last[kTilePixels];
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
            behind[p] =
                (gr[p] * background[0] + gg[p] * background[1] + gb[p] * background[2] - ga) * T[p];
            last[p] = last_in[o];
            row_last[py] = std::max(row_last[py], last[p]);
        }
        tile_last = std::max(tile_last, row_last[py]);
    }

    const int64_t n = int64_t(G.size());
    const int64_t n_used = std::min<int64_t>(n, tile_last);
    for (int64_t j = n_used; j < n; ++j)
        std::fill_n(entry_grad + slot[j] * kEntryGrad, kEntryGrad, 0.0f);
    const vf centre[2] = {lane_centres(0), lane_centres(1)};
    for (int64_t j = n_used - 1; j >= 0; --j) {
        const TileSplat& s = G[j];
        const vi jj = splat_i(int32_t(j));
        // Gradients of the falloff power p = -(ca dx^2 + 2 cb dx dy + cc dy^2) / 2 enter
        // through its moments: m_x = sum dp dx, m_y = sum dp dy, m_xx, m_xy, m_yy.
        vf m_x{}, m_y{}, m_xx{}, m_xy{}, m_yy{}, d_op{}, d_r{}, d_g{}, d_b{}, d_z{};
        for (int py = s.row0; py <= s.row1; ++py) {
            if (row_last[py] <= j) continue;
            const float dy = s.y - (float(py) + 0.5f);
            for (int h = s.half0; h <= s.half1; ++h) {
                const int p = py * kTile + h * kLanes;
                const Falloff fo = falloff(s, centre[h], dy);
                const vi ok = fo.ok & (jj < load(last + p));
                const vf a = ok ? fo.a : splat(0.0f);
                const vf inv_one_minus = 1.0f / (1.0f - a);
                const vf Tj = load(T + p) * inv_one_minus;
                const vf pr = load(gr + p), pg = load(gg + p), pb = load(gb + p);
                const vf pz = load(gz + p);
                const vf gp = pr * s.r + pg * s.g + pb * s.b + pz * s.z;
                const vf w = a * Tj;
                const vf beh = load(behind + p);
                const vf d_alpha = Tj * gp - beh * inv_one_minus;
                store(behind + p, beh + w * gp);
                store(T + p, Tj);
                d_r += pr * w;
                d_g += pg * w;
                d_b += pb * w;
                d_z += pz * w;
                // alpha = min(0.99, op * vis): no gradient through the clamp
                const vf da = ok & (s.op * fo.vis <= kAlphaMax) ? d_alpha : splat(0.0f);
                d_op += da * fo.vis;
                const vf d_pow = da * fo.a;
                const vf wx = d_pow * fo.dx, wy = d_pow * dy;
                m_x += wx;
                m_y += wy;
                m_xx += wx * fo.dx;
                m_xy += wx * dy;
                m_yy += wy * dy;
            }
        }
        const float sx = lane_sum(m_x), sy = lane_sum(m_y);
        float* e = entry_grad + slot[j] * kEntryGrad;
        e[0] = -(s.ca * sx + s.cb * sy);  // dp/dmean_x = -(ca dx + cb dy)
        e[1] = -(s.cb * sx + s.cc * sy);
        e[2] = -0.5f * lane_sum(m_xx);
        e[3] = -lane_sum(m_xy);
        e[4] = -0.5f * lane_sum(m_yy);
        e[5] = lane_sum(d_op);
        e[6] = lane_sum(d_r);
        e[7] = lane_sum(d_g);
        e[8] = lane_sum(d_b);
        e[9] = lane_sum(d_z);
    }
}

}  // namespace ah
