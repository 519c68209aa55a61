// A triangle mesh's nearest face at each pixel centre, with a z-buffer: the tracker's
// head-and-neck masks and the trainer's part masks take one per frame (parts_mask.py), where
// the numpy form took 0.36 s a frame at 512 px. Every operation is written as the numpy
// reference writes it (double precision, no fused operations: -ffp-contract=off), so both
// give the same faces and barycentrics bit for bit.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace ah {

// Twice the signed area of (u, v, q).
inline double edge(const double* u, const double* v, double qx, double qy) {
    return (v[0] - u[0]) * (qy - u[1]) - (v[1] - u[1]) * (qx - u[0]);
}

// Faces in order; a later face wins a pixel only when strictly nearer (1/z larger), so ties
// go to the earlier one.
inline void rasterize_mesh(int64_t n_faces, const double* xy, const double* z,
                           const int64_t* faces, int32_t width, int32_t height,
                           int64_t* face_at, double* bary) {
    const int64_t pixels = int64_t(width) * height;
    std::vector<double> depth(pixels, -std::numeric_limits<double>::infinity());
    for (int64_t p = 0; p < pixels; ++p) {
        face_at[p] = -1;
        bary[3 * p] = bary[3 * p + 1] = bary[3 * p + 2] = 0.0;
    }
    for (int64_t f = 0; f < n_faces; ++f) {
        const int64_t* v = faces + 3 * f;
        const double *a = xy + 2 * v[0], *b = xy + 2 * v[1], *c = xy + 2 * v[2];
        const double area = edge(a, b, c[0], c[1]);
        if (area == 0.0 || !std::isfinite(area)) continue;
        // Columns covered by [x0, x1]: ceil(x0 - 0.5) .. floor(x1 - 0.5), likewise rows.
        const double x0 = std::fmin(std::fmin(a[0], b[0]), c[0]);
        const double x1 = std::fmax(std::fmax(a[0], b[0]), c[0]);
        const double y0 = std::fmin(std::fmin(a[1], b[1]), c[1]);
        const double y1 = std::fmax(std::fmax(a[1], b[1]), c[1]);
        const double col_lo = std::fmax(std::ceil(x0 - 0.5), 0.0);
        const double col_hi = std::fmin(std::floor(x1 - 0.5), double(width - 1));
        const double row_lo = std::fmax(std::ceil(y0 - 0.5), 0.0);
        const double row_hi = std::fmin(std::floor(y1 - 0.5), double(height - 1));
        if (col_lo > col_hi || row_lo > row_hi) continue;
        const double za = z[v[0]], zb = z[v[1]], zc = z[v[2]];
        for (int64_t row = int64_t(row_lo); row <= int64_t(row_hi); ++row) {
            const double py = double(row) + 0.5;
            for (int64_t col = int64_t(col_lo); col <= int64_t(col_hi); ++col) {
                const double px = double(col) + 0.5;
                const double w0 = edge(b, c, px, py) / area;
                const double w1 = edge(c, a, px, py) / area;
                const double w2 = edge(a, b, px, py) / area;
                if (!(w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0)) continue;
                const double q0 = w0 / za, q1 = w1 / zb, q2 = w2 / zc;
                const double inv_z = q0 + q1 + q2;
                const int64_t p = row * width + col;
                if (!(inv_z > depth[p])) continue;
                depth[p] = inv_z;
                face_at[p] = f;
                bary[3 * p] = q0 / inv_z;
                bary[3 * p + 1] = q1 / inv_z;
                bary[3 * p + 2] = q2 / inv_z;
            }
        }
    }
}

}  // namespace ah
