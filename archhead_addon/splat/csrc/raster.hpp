// Per-tile compositing, forward and backward. One thread owns a whole tile (32 x 32 pixels
// on the AVX-512 path, 16 x 16 on the others: Kernels::tile) and walks its Gaussians in depth
// order; for each Gaussian it updates the pixels of the tile that the Gaussian's ellipse
// reaches, 4 (4 x 1, baseline), 8 (4 x 2, AVX2) or 16 (4 columns x 4 rows, AVX-512) at a
// time with GCC vector extensions (explicit, so the code vectorises whatever the optimiser's
// heuristics). `Raster<Layout>` (raster_lanes.hpp) is compiled once per instruction set
// (dispatch.hpp picks one at run time); this file holds what they share.
// Every lane runs the same float operations in the same order, so the AVX2 and AVX-512 paths
// give bitwise identical images (gradients differ by the order of the lane sums only); the
// baseline path, without FMA, rounds the products of the fused operations separately.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <utility>
#include <vector>

#include "binning.hpp"
#include "projection.hpp"

#ifdef __x86_64__
#include <immintrin.h>  // movemasks (raster_lanes.hpp), each used under its target only
#endif

namespace ah {

// Where a Gaussian can pass the alpha test, row by row, so that the compositing skips the
// steps outside its ellipse. With d = (x_mean - x, dy), q = d^T conic d is smallest over x
// at x = x_mean + slope dy, and q <= q_max holds within sqrt(w2) of there, w2 = (q - g dy^2)
// inv_ca. Conservative: q is q_max raised by far more than the float32 round-off of the
// falloff's power at any lane a step evaluates (relative to the size of its terms), and
// the spans (Lanes::row_spans) are kSpanMargin wider, so a step skipped holds no lane that
// the alpha test would pass: images and gradients equal those of the whole box. The box's
// span (whole rows): slope = g = 0, inv_ca = 1, q = inf.
struct Span {
    float slope, g, inv_ca, q;
};
constexpr float kSpanMargin = 1.0f;  // pixels

// A Gaussian as one tile reads it: 2D mean relative to the tile's grid origin (TileFrame;
// small numbers keep the float32 offsets accurate), conic, opacity, colour, depth, its Span,
// and the rows and columns of the tile its box covers.
struct TileSplat {
    float x, y, ca, cb, cc, op, r, g, b, z;
    Span span;
    int32_t row0, row1, col0, col1;
};

// A Gaussian as the tiles read it (ProjectLanes::project_range), one record each, in
// input order (which keeps a tile's Gaussians close in memory where the input is ordered
// by position, as a UV-parameterised avatar's is).
struct Splat2D {
    double x, y;
    float ca, cb, cc, op, r, g, b, z;
    Span span;
    int32_t bbox[4];
};

// A tile: origin and edge in pixels, the image size. Float coordinates are taken from the
// grid origin, the corner of the kMaxTile tile that holds it, whatever the path's tile size:
// the same float32 values, so that the paths' images agree bit for bit.
struct TileFrame {
    int ox, oy, size, width, height;
    int grid_x() const { return ox % kMaxTile; }  // the origin, from the grid origin
    int grid_y() const { return oy % kMaxTile; }
};

// Gaussian p as tile f reads it.
inline TileSplat tile_splat(const Splat2D& p, const TileFrame& f) {
    const int ox = f.ox, oy = f.oy;
    TileSplat s;
    s.x = float(p.x - (ox - f.grid_x()));
    s.y = float(p.y - (oy - f.grid_y()));
    s.ca = p.ca;
    s.cb = p.cb;
    s.cc = p.cc;
    s.op = p.op;
    s.r = p.r;
    s.g = p.g;
    s.b = p.b;
    s.z = p.z;
    s.span = p.span;
    s.col0 = std::max(p.bbox[0] - ox, 0);
    s.col1 = std::min(p.bbox[1] - ox, f.size - 1);
    s.row0 = std::max(p.bbox[2] - oy, 0);
    s.row1 = std::min(p.bbox[3] - oy, f.size - 1);
    return s;
}

// What the forward records for the backward, appended per tile: see
// Raster::composite_forward. Grown, never shrunk, so that a reused context keeps its memory.
struct StepRecords {
    std::vector<float> data;
    int64_t size = 0;
    float* reserve(int64_t n) {  // room for n more values after size
        if (size + n > int64_t(data.size()))
            data.resize(std::max<int64_t>(2 * int64_t(data.size()), size + n));
        return data.data() + size;
    }
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
