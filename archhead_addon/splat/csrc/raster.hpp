// Per-tile compositing, forward and backward. One thread owns a whole 16x16 tile and
// walks its Gaussians in depth order; for each Gaussian it updates the pixels of the tile
// that the Gaussian's box covers, 8 (one row, AVX2) or 16 (8 columns x 2 rows, AVX-512) at a
// time with GCC vector extensions (explicit, so the code vectorises whatever the optimiser's
// heuristics). `Raster<Layout>` (raster_lanes.hpp) is compiled once per instruction set
// (dispatch.hpp picks one at run time); this file holds what they share. Every lane runs
// the same float operations in the same order, so the images are bitwise identical across
// the paths (gradients differ by the order of the lane sums only).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

#include "binning.hpp"
#include "projection.hpp"

#ifdef __x86_64__
#include <immintrin.h>  // movemasks (raster_lanes.hpp), each used under its target only
#endif

namespace ah {

constexpr int kTilePixels = kTile * kTile;

// A Gaussian as one tile reads it: 2D mean relative to the tile origin (small numbers keep
// the float32 offsets accurate), conic, opacity, colour, depth, the bound q_max of its
// ellipse (Bounds), and the rows and columns of the tile its box covers.
struct TileSplat {
    float x, y, ca, cb, cc, op, r, g, b, z, q_max;
    int32_t row0, row1, col0, col1;
};

// Projected Gaussians in input order (SoA), as the rasteriser reads them.
struct Projected {
    std::vector<double> mean2d;  // 2 per Gaussian
    std::vector<float> conic;    // 3
    std::vector<float> opacity;
    std::vector<float> depth;
    std::vector<int32_t> bbox;  // 4: x0, x1, y0, y1 inclusive
    std::vector<float> q_max;
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
        s.q_max = P.q_max[id];
        s.col0 = std::max(P.bbox[4 * id] - ox, 0);
        s.col1 = std::min(P.bbox[4 * id + 1] - ox, kTile - 1);
        s.row0 = std::max(P.bbox[4 * id + 2] - oy, 0);
        s.row1 = std::min(P.bbox[4 * id + 3] - oy, kTile - 1);
    }
}

// Where a Gaussian can pass the alpha test, row by row, so that the compositing steps can
// skip what lies outside its ellipse. With d = (s.x - x, dy), q = d^T conic d is smallest
// over x at x = s.x + slope dy, and q <= q_max holds within sqrt(w2) of there, w2 = (q_max -
// g dy^2) / ca. Conservative: q_max is raised by far more than the float32 round-off of the
// falloff's power over the tile's box (relative to the size of its terms) and spans are
// widened by a pixel, so a step skipped holds no lane that the alpha test would pass (the
// images and gradients equal those of the whole box). Where a coefficient is not finite
// every step of the box is taken.
struct Ellipse {
    float x, slope, g, inv_ca, q;
    bool box;  // no bounds: every step of the box

    Ellipse(const TileSplat& s, bool use) {
        x = s.x;
        inv_ca = 1.0f / s.ca;
        slope = s.cb * inv_ca;
        g = s.cc - s.cb * slope;
        const float X = std::max(std::fabs(s.x - (float(s.col0) + 0.5f)),
                                 std::fabs(s.x - (float(s.col1) + 0.5f)));
        const float Y = std::max(std::fabs(s.y - (float(s.row0) + 0.5f)),
                                 std::fabs(s.y - (float(s.row1) + 0.5f)));
        const float terms = s.ca * X * X + 2.0f * std::fabs(s.cb) * X * Y + s.cc * Y * Y;
        q = s.q_max + 1e-5f * terms;
        box = !(use && std::isfinite(inv_ca) && std::isfinite(slope) && std::isfinite(g) &&
                std::isfinite(q));
    }
    // Whether the row at dy may pass the alpha test at a pixel centre in [first, last].
    bool reaches(float dy, float first, float last) const {
        if (box) return true;
        const float c = x + slope * dy, w2 = (q - g * dy * dy) * inv_ca;
        const float d = std::max(std::max(first - 1.0f - c, c - last - 1.0f), 0.0f);
        return w2 >= d * d;
    }
};

struct TileFrame {
    int ox, oy, width, height;  // tile origin in pixels, image size
};

constexpr int kLiveCheck = 16;  // Gaussians between checks for finished rows / tiles
constexpr int kEntryGrad = 10;  // d mean2d (2), d conic (3), d opacity, d rgb (3), d depth

// GCC vector types of L floats / int32s (specialised: a vector_size that depends on a
// template parameter is not applied in a template's definition).
template <int L>
struct Vectors;
template <>
struct Vectors<4> {
    typedef float f __attribute__((vector_size(16)));
    typedef int32_t i __attribute__((vector_size(16)));
};
template <>
struct Vectors<8> {
    typedef float f __attribute__((vector_size(32)));
    typedef int32_t i __attribute__((vector_size(32)));
};
template <>
struct Vectors<16> {
    typedef float f __attribute__((vector_size(64)));
    typedef int32_t i __attribute__((vector_size(64)));
};

}  // namespace ah
