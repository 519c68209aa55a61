// ArchHead splat kernel: plain C ABI, called through ctypes (numpy) and wrapped by a
// torch.autograd.Function. All arrays are C-contiguous float32 unless noted.
//
// Conventions
//   camera     OpenCV: x right, y down, z forward; viewmat is world-to-camera, 4x4 row-major,
//              affine (its 3x3 block may be any invertible linear map, e.g. include an object
//              transform); K is 3x3 row-major in pixels, no skew; pixel (i, j) has its centre
//              at (i + 0.5, j + 0.5) in the coordinates K maps to.
//   gaussians  means (N,3); log_scales (N,3), clamped to [AH_LOG_SCALE_MIN, AH_LOG_SCALE_MAX]
//              before exp; quats (N,4) w,x,y,z, normalised inside (a zero quaternion is the
//              identity); opacity_logits (N); colors (N,3) (already evaluated from SH).
//   outputs    rgb (H,W,3) composited over the background; alpha (H,W) = 1 - transmittance;
//              depth (H,W) = sum_i w_i z_i, the alpha-weighted camera z (divide by alpha for
//              the expected depth; the Python layer does).
#ifndef ARCHHEAD_SPLAT_H
#define ARCHHEAD_SPLAT_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define AH_SPLAT_ABI_VERSION 5
#define AH_LOG_SCALE_MIN -23.0f  // scale 1e-10
#define AH_LOG_SCALE_MAX 11.5f   // scale ~1e5

typedef struct {
    int32_t width, height;
    double viewmat[16];  // row-major
    double K[9];         // row-major
    float near_plane, far_plane;
    float eps2d;          // isotropic dilation of the 2D covariance, px^2 (3DGS: 0.3)
    int32_t antialiased;  // 1: scale opacity by sqrt(det(cov) / det(cov + eps2d I))
    float background[3];
    int32_t num_threads;  // <= 0: OpenMP default
    // ah_splat_forward: 1 to keep what ah_splat_backward needs (the falloff of the
    // composited steps: about 5 % of the forward's time), 0 for an image alone (its context
    // then refuses a backward). ah_splat_project ignores it.
    int32_t for_backward;
} ah_splat_params;

// Per-Gaussian projection (exposed for tests and diagnostics). Culled Gaussians get
// radii (0, 0) and zeros elsewhere.
// means2d (N,2) float64, conics (N,3) (a, b, c of [[a,b],[b,c]]), depths (N), opacities (N)
// (sigmoid of the logit, times the compensation when antialiased), radii (N,2) int32.
int ah_splat_project(const ah_splat_params* params, int64_t n, const float* means,
                     const float* log_scales, const float* quats, const float* opacity_logits,
                     double* means2d, float* conics, float* depths, float* opacities,
                     int32_t* radii, char* err, int32_t err_len);

// Renders and returns an opaque context holding what the backward pass needs (free it with
// ah_splat_release), or NULL with a message in err.
void* ah_splat_forward(const ah_splat_params* params, int64_t n, const float* means,
                       const float* log_scales, const float* quats, const float* opacity_logits,
                       const float* colors, float* out_rgb, float* out_alpha, float* out_depth,
                       char* err, int32_t err_len);

// Gradients of a scalar loss given dL/d(rgb, alpha, depth) (g_alpha / g_depth may be NULL
// for zero). Writes (overwrites) all five gradient arrays. Returns 0, or -1 with err set.
int ah_splat_backward(void* ctx, const float* g_rgb, const float* g_alpha, const float* g_depth,
                      float* d_means, float* d_log_scales, float* d_quats, float* d_opacity_logits,
                      float* d_colors, char* err, int32_t err_len);

// AH_SPLAT_STATS_LEN entries: Gaussians that survived culling, tile intersections, then
// wall-clock nanoseconds of the phases: projection, sort and binning, compositing (the
// forward's three), backward compositing, backward per-Gaussian reduction and projection VJP
// (0 before the backward ran); the AH_ISA_* the forward ran with; the forward compositing's
// pixel lanes evaluated, and those of them that composited a sample.
#define AH_SPLAT_STATS_LEN 10
void ah_splat_stats(const void* ctx, int64_t* stats);

void ah_splat_release(void* ctx);

// Instruction sets of the hot loops, chosen at run time (the best the CPU has by default).
#define AH_ISA_AUTO -1
#define AH_ISA_BASELINE 0  // x86-64 SSE2, or the plain build on other architectures
#define AH_ISA_AVX2 1
#define AH_ISA_AVX512 2  // avx512f, bw, dq, vl
// Selects the instruction set for the following forward passes (a backward uses its
// forward's) and returns it; AH_ISA_AUTO picks the best supported. Returns -1, changing
// nothing, when the CPU or the build lacks it. Not to be called while a render runs.
int32_t ah_splat_select_isa(int32_t isa);
// 1 when this CPU and build can run `isa`, else 0.
int32_t ah_splat_isa_supported(int32_t isa);
// 1 (the default): the compositing skips the steps that lie outside each Gaussian's
// ellipse; 0: it takes every step of the Gaussian's box (same images and gradients, for
// tests and benchmarks). Applies to the following forward passes (and their backward
// passes); returns the previous setting. Not to be called while a render runs.
int32_t ah_splat_set_ellipse_steps(int32_t on);

// Not a splat: the nearest face of a projected triangle mesh at each pixel centre (pixel (i, j)
// centred at (j + 0.5, i + 0.5)), with a z-buffer; the masks' rasterizer (parts_mask.py).
// xy (V,2) pixels and z (V) camera depths, float64; faces (F,3) int64 vertex indices, each
// face's vertices in front of the camera; ties go to the earlier face. Writes face_at (H,W)
// int64 (the face's row in `faces`, -1 where none) and bary (H,W,3) float64, the
// perspective-correct barycentrics (0 where none). Returns 0, or -1 with err set.
int ah_mesh_rasterize(int64_t n_vertices, int64_t n_faces, const double* xy, const double* z,
                      const int64_t* faces, int32_t width, int32_t height, int64_t* face_at,
                      double* bary, char* err, int32_t err_len);

// Not a splat: the sRGB encoding of a linear image as training takes it (colour_space.py's
// linear_to_srgb: x clamped to [0, 1], 12.92 x up to 0.0031308, 1.055 x^(1/2.4) - 0.055
// above) and its derivative, so that the backward pass is one product. Writes y and slope, n
// values each: dy/dx, 0 where x lies outside (0, 1) as torch.clamp's gradient is.
// num_threads <= 0: the OpenMP default (both functions here).
void ah_srgb_encode(int64_t n, const float* x, float* y, float* slope, int32_t num_threads);

// Not a splat: training's two image terms in one pass (train/losses.py), Huber(pred, target)
// and Huber(pred * B, target * B), B one weight a pixel (`parts`), 1-4 channels: each the
// mean over the n_pixels * channels values of torch's huber_loss (0.5 d^2 where |d| < delta,
// delta (|d| - 0.5 delta) beyond), and their gradients with respect to pred. Writes terms[2]
// (summed in a fixed order: the same bits at any thread count), grad_rgb and grad_parts
// (n_pixels * channels each).
void ah_image_huber(int64_t n_pixels, int32_t channels, const float* pred, const float* target,
                    const float* parts, float delta, double* terms, float* grad_rgb,
                    float* grad_parts, int32_t num_threads);

// Not a splat: one level of the avatar's feature field (c, s, s) resized bicubically to
// size x size by its taps (index and weight (size, 4), avatar/bicubic.py; index NULL when s ==
// size) and read at n distinct texels (flat row * size + column): out (n, c) += blend * it.
// The backward overwrites grad_f (c, s, s) with the gradient given grad (n, c).
// csrc/resample.hpp.
void ah_resample_forward(int32_t c, int32_t s, const float* f, int32_t size, const int32_t* index,
                         const float* weight, float blend, int64_t n, const int64_t* texel,
                         float* out, int32_t num_threads);
void ah_resample_backward(int32_t c, int32_t s, int32_t size, const int32_t* index,
                          const float* weight, float blend, int64_t n, const int64_t* texel,
                          const float* grad, float* grad_f, int32_t num_threads);

int32_t ah_splat_abi_version(void);

#ifdef __cplusplus
}
#endif

#endif
