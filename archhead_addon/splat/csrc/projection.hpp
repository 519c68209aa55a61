// EWA projection of 3D Gaussians: what the instruction-set versions of the projection
// (projection_lanes.hpp) share. Everything per Gaussian runs in double: it is cheap (N, not
// pixels) and keeps extreme scales (1e-10 .. 1e5 m), their ratios and the 2D determinant
// (a c - b^2, which cancels for thin splats seen edge-on) accurate; the rasteriser gets
// float32 results.
#pragma once

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdint>

#include "splat.h"

namespace ah {

constexpr float kAlphaMin = 1.0f / 255.0f;  // samples below this are skipped
constexpr float kAlphaMax = 0.99f;          // alpha clamp
constexpr float kTransmittanceMin = 1e-4f;  // a pixel stops once T would fall below this
constexpr double kQuatNormEps = 1e-12;      // |q| guard, as F.normalize
constexpr double kDetMin = 1e-10;           // dilated 2D covariance determinant guard

struct Camera {
    double V[9], t[3];  // world-to-camera linear part and translation
    double fx, fy, cx, cy;
    int width, height;
    double near_plane, far_plane, eps2d;
    bool antialiased;
    // Camera-space x/z and y/z are clamped to the view frustum plus 30% when building the
    // EWA Jacobian (as 3DGS / gsplat), so off-screen Gaussians do not explode.
    double lim_x_pos, lim_x_neg, lim_y_pos, lim_y_neg;

    explicit Camera(const ah_splat_params& p) {
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) V[3 * i + j] = p.viewmat[4 * i + j];
            t[i] = p.viewmat[4 * i + 3];
        }
        fx = p.K[0];
        fy = p.K[4];
        cx = p.K[2];
        cy = p.K[5];
        width = p.width;
        height = p.height;
        near_plane = p.near_plane;
        far_plane = p.far_plane;
        eps2d = p.eps2d;
        antialiased = p.antialiased != 0;
        const double tan_fovx = 0.5 * width / fx, tan_fovy = 0.5 * height / fy;
        lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx;
        lim_x_neg = cx / fx + 0.3 * tan_fovx;
        lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy;
        lim_y_neg = cy / fy + 0.3 * tan_fovy;
    }
};

// float64 vector types of L lanes and their masks (see Vectors in raster.hpp).
template <int L>
struct DVectors;
template <>
struct DVectors<2> {
    typedef double d __attribute__((vector_size(16)));
    typedef int64_t m __attribute__((vector_size(16)));
};
template <>
struct DVectors<4> {
    typedef double d __attribute__((vector_size(32)));
    typedef int64_t m __attribute__((vector_size(32)));
};
template <>
struct DVectors<8> {
    typedef double d __attribute__((vector_size(64)));
    typedef int64_t m __attribute__((vector_size(64)));
};

// The kernel's inputs (splat.h), as the projection reads them.
struct Gaussians {
    const float *means, *log_scales, *quats, *logits;
};

struct Splat2D;  // raster.hpp

// Where the projection writes, per Gaussian in input order: ah_splat_project's arrays, zeroed
// by the caller (null in the forward), or the forward's (null in ah_splat_project): every
// Gaussian's visible flag and a visible one's box (inclusive pixel ranges x0, x1, y0, y1),
// float64 depth (for the sort) and Splat2D (its colour from colors; its Span the box's
// unless ellipse).
struct ProjectOut {
    double* mean2d;
    float *conic, *opacity, *depth;
    int32_t* radii;
    uint8_t* visible;
    int32_t* bbox;
    double* depth64;
    Splat2D* splats;
    const float* colors;
    bool ellipse;
};

struct GradOut {
    float *d_means, *d_log_scales, *d_quats, *d_logits;
};

// Gradients are computed in double; huge but finite ones (e.g. through the normalisation of
// a 1e-30 quaternion) saturate instead of overflowing float32 to Inf.
inline float saturate(double x) { return float(std::clamp(x, -double(FLT_MAX), double(FLT_MAX))); }

}  // namespace ah
