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
#include <cstdint>
#include <cstring>
#include <vector>

#include "binning.hpp"
#include "projection.hpp"

namespace ah {

constexpr int kTilePixels = kTile * kTile;

// A Gaussian as one tile reads it: 2D mean relative to the tile origin (small numbers keep
// the float32 offsets accurate), conic, opacity, colour, depth, and the rows and columns of
// the tile its box covers.
struct TileSplat {
    float x, y, ca, cb, cc, op, r, g, b, z;
    int32_t row0, row1, col0, col1;
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
        s.col0 = std::max(P.bbox[4 * id] - ox, 0);
        s.col1 = std::min(P.bbox[4 * id + 1] - ox, kTile - 1);
        s.row0 = std::max(P.bbox[4 * id + 2] - oy, 0);
        s.row1 = std::min(P.bbox[4 * id + 3] - oy, kTile - 1);
    }
}

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
