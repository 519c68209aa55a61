// C ABI of the ArchHead splat kernel (see splat.h).
//
// Determinism: every parallel loop writes disjoint outputs (a Gaussian, a tile), and the
// backward pass stores one gradient record per tile intersection instead of accumulating
// into shared or per-thread buffers; each Gaussian then sums its own records in tile
// order. Results are therefore bitwise identical for any thread count.
#include "splat.h"

#include <omp.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <memory>
#include <mutex>
#include <new>
#include <vector>

#include "binning.hpp"
#include "dispatch.hpp"
#include "mesh_raster.hpp"
#include "projection.hpp"
#include "raster.hpp"
#include "resample.hpp"

namespace {

using namespace ah;

void set_error(char* err, int32_t err_len, const char* msg) {
    if (err && err_len > 0) std::snprintf(err, size_t(err_len), "%s", msg);
}

bool check_params(const ah_splat_params* p, char* err, int32_t err_len) {
    char msg[256];
    auto fail = [&](const char* what) {
        std::snprintf(msg, sizeof msg, "invalid splat parameters: %s", what);
        set_error(err, err_len, msg);
        return false;
    };
    if (!p) return fail("params is NULL");
    if (p->width <= 0 || p->height <= 0 || p->width > 32768 || p->height > 32768)
        return fail("width and height must be in 1..32768");
    for (double v : p->viewmat)
        if (!std::isfinite(v)) return fail("viewmat has a non-finite entry");
    for (double v : p->K)
        if (!std::isfinite(v)) return fail("K has a non-finite entry");
    // The kernel reads only the 3x4 block of viewmat and fx, fy, cx, cy of K; reject
    // anything else (allowing round-off from matrix inversion).
    auto near = [](double a, double b) { return std::fabs(a - b) <= 1e-9 * (1 + std::fabs(b)); };
    const double* v = p->viewmat;
    if (!(near(v[12], 0) && near(v[13], 0) && near(v[14], 0) && near(v[15], 1)))
        return fail("viewmat's last row must be [0, 0, 0, 1]");
    const double* K = p->K;
    if (!(near(K[1] / K[0], 0) && near(K[3], 0) && near(K[6], 0) && near(K[7], 0) && near(K[8], 1)))
        return fail("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)");
    if (!(K[0] > 0 && K[4] > 0)) return fail("K[0,0] and K[1,1] must be positive");
    if (!(std::isfinite(p->near_plane) && p->near_plane > 0))
        return fail("near_plane must be positive and finite");
    if (!(p->far_plane > p->near_plane)) return fail("far_plane must exceed near_plane");
    if (!(std::isfinite(p->eps2d) && p->eps2d >= 0)) return fail("eps2d must be >= 0");
    for (float v : p->background)
        if (!std::isfinite(v)) return fail("background has a non-finite entry");
    return true;
}

Kernels& active_kernels() {
    static Kernels k = kernels_for(best_isa());
    return k;
}

bool& ellipse_steps() {
    static bool on = true;
    return on;
}

// a num_threads argument: <= 0 is the OpenMP default
int thread_count(int32_t num_threads) {
    return num_threads > 0 ? num_threads : omp_get_max_threads();
}

int thread_count(const ah_splat_params& p) { return thread_count(p.num_threads); }

struct Context {
    ah_splat_params params;
    Camera cam;
    Kernels kernels;  // the forward's, so that its backward runs the same lanes
    bool ellipse;     // the forward skipped the steps outside each Gaussian's ellipse
    bool recorded;    // the forward kept its step records (params.for_backward)
    int64_t n;
    std::vector<float> means, log_scales, quats, logits, colors;
    std::vector<int32_t> bbox;  // per Gaussian: x0, x1, y0, y1 (ProjectOut)
    Bins bins;
    std::vector<Splat2D> splats;         // per Gaussian, input order
    std::vector<TileSplat> tile_splats;  // per tile-list entry (bins.tile_ids)
    std::vector<float> T_final;
    // per thread, the records of its tiles' steps (StepRecords); per tile, which thread's
    // and from where
    std::vector<StepRecords> records;
    std::vector<int32_t> tile_thread;
    std::vector<int64_t> record_start;  // per tile-list entry, in its thread's records
    std::vector<uint64_t> step_mask;    // per tile-list entry: its steps that drew a sample
    // scratch of the passes, kept with the context for reuse (see acquire)
    std::vector<double> depth64;
    std::vector<uint8_t> visible;
    std::vector<int32_t> ids;
    std::vector<float> entry_grad;
    // Wall-clock seconds of the phases, for the benchmark's split (ah_splat_stats).
    double t_project = 0, t_bin = 0, t_composite = 0, t_bwd_composite = 0, t_bwd_project = 0;
    int64_t lanes_evaluated = 0, lanes_used = 0;  // compositing's pixel lanes (forward)

    Context(const ah_splat_params& p, int64_t n_)
        : params(p),
          cam(p),
          kernels(active_kernels()),
          ellipse(ellipse_steps()),
          recorded(p.for_backward != 0),
          n(n_) {}
};

// Released contexts are kept (up to kPooled) and reused by the next forward passes with
// their buffers: fresh buffers of tens of MB are mapped page by page on first touch, which
// costs about as much as compositing a small image.
constexpr size_t kPooled = 1;
std::mutex pool_mutex;
std::vector<std::unique_ptr<Context>> pool;

std::unique_ptr<Context> acquire(const ah_splat_params& p, int64_t n) {
    std::unique_ptr<Context> C;
    {
        const std::lock_guard<std::mutex> lock(pool_mutex);
        if (!pool.empty()) {
            C = std::move(pool.back());
            pool.pop_back();
        }
    }
    if (!C) return std::make_unique<Context>(p, n);
    C->params = p;
    C->cam = Camera(p);
    C->kernels = active_kernels();
    C->ellipse = ellipse_steps();
    C->recorded = p.for_backward != 0;
    C->n = n;
    C->t_project = C->t_bin = C->t_composite = C->t_bwd_composite = C->t_bwd_project = 0;
    C->lanes_evaluated = C->lanes_used = 0;
    return C;
}

void release(Context* ctx) {
    std::unique_ptr<Context> C(ctx);
    const std::lock_guard<std::mutex> lock(pool_mutex);
    if (pool.size() < kPooled) pool.push_back(std::move(C));
}

constexpr int64_t kProjectBlock = 256;  // Gaussians per parallel work item (a lane multiple)

Gaussians inputs(const Context& C) {
    return Gaussians{C.means.data(), C.log_scales.data(), C.quats.data(), C.logits.data()};
}

// Projects every Gaussian into out with the kernels' projection, in parallel blocks.
void project_blocks(const Kernels& K, const Camera& cam, const Gaussians& g, int64_t n,
                    const ProjectOut& out, int threads) {
#pragma omp parallel for num_threads(threads) schedule(static)
    for (int64_t b = 0; b < n; b += kProjectBlock)
        K.project_range(cam, g, b, std::min(b + kProjectBlock, n), out);
}

TileFrame frame_of(const Context& C, int64_t tile) {
    const int size = C.bins.tile;
    return TileFrame{int(tile % C.bins.tiles_x) * size, int(tile / C.bins.tiles_x) * size, size,
                     C.params.width, C.params.height};
}

// The tile lists' Gaussians as the tiles read them, once for the forward and the backward.
void gather_tiles(Context& C) {
    const int64_t n_tiles = int64_t(C.bins.tiles_x) * C.bins.tiles_y;
    C.tile_splats.resize(C.bins.tile_ids.size());
#pragma omp parallel for num_threads(thread_count(C.params)) schedule(static)
    for (int64_t t = 0; t < n_tiles; ++t) {
        const TileFrame f = frame_of(C, t);
        const int64_t e = C.bins.tile_start[t + 1];
        for (int64_t p = C.bins.tile_start[t]; p < e; ++p) {
            if (p + 16 < e) {  // random reads: both cache lines of the record 16 entries on
                const char* next =
                    reinterpret_cast<const char*>(&C.splats[C.bins.tile_ids[p + 16]]);
                __builtin_prefetch(next);
                __builtin_prefetch(next + 64);
            }
            C.tile_splats[p] = tile_splat(C.splats[C.bins.tile_ids[p]], f);
        }
    }
}

void project_all(Context& C) {
    const int64_t n = C.n;
    C.bbox.resize(4 * n);
    C.depth64.resize(n);
    C.visible.resize(n);
    C.splats.resize(n);
    const double t0 = omp_get_wtime();
    const ProjectOut out{nullptr,         nullptr,          nullptr,       nullptr,
                         nullptr,         C.visible.data(), C.bbox.data(), C.depth64.data(),
                         C.splats.data(), C.colors.data(),  C.ellipse};
    project_blocks(C.kernels, C.cam, inputs(C), n, out, thread_count(C.params));
    const double t1 = omp_get_wtime();
    C.t_project = t1 - t0;
    C.ids.clear();
    for (int64_t i = 0; i < n; ++i)
        if (C.visible[i]) C.ids.push_back(int32_t(i));
    bin_tiles(C.bins, sort_by_depth(C.ids, C.depth64), C.bbox, C.params.width, C.params.height,
              C.kernels.tile, thread_count(C.params));
    gather_tiles(C);
    C.t_bin = omp_get_wtime() - t1;
}

// Runs body(G, frame, first_entry, tile) for every tile in parallel, G holding the tile's
// tile_splats, front to back; dynamic scheduling because tiles differ widely in load.
template <class Body>
void for_each_tile(Context& C, Body&& body) {
    const int64_t n_tiles = int64_t(C.bins.tiles_x) * C.bins.tiles_y;
#pragma omp parallel for num_threads(thread_count(C.params)) schedule(dynamic, 1)
    for (int64_t t = 0; t < n_tiles; ++t) {
        const int64_t s = C.bins.tile_start[t];
        body(&C.tile_splats[s], C.bins.tile_start[t + 1] - s, frame_of(C, t), s, t);
    }
}

void render(Context& C, float* rgb, float* alpha, float* depth) {
    const int64_t pixels = int64_t(C.params.width) * C.params.height;
    C.T_final.assign(pixels, 1.0f);
    C.step_mask.assign(C.bins.tile_ids.size(), 0);
    const int64_t n_tiles = int64_t(C.bins.tile_start.size()) - 1;
    C.records.resize(thread_count(C.params));
    for (StepRecords& r : C.records) r.size = 0;
    C.tile_thread.resize(n_tiles);
    C.record_start.resize(C.bins.tile_ids.size());
    std::vector<int64_t> lanes(2 * n_tiles);
    const double t0 = omp_get_wtime();
    for_each_tile(C, [&](const TileSplat* G, int64_t n, const TileFrame& f, int64_t s, int64_t t) {
        const int thread = omp_get_thread_num();
        C.tile_thread[t] = thread;
        C.kernels.composite_forward(
            G, n, f, C.params.background, rgb, alpha, depth, C.T_final.data(), &C.step_mask[s],
            C.recorded ? &C.records[thread] : nullptr, &C.record_start[s], &lanes[2 * t]);
    });
    C.t_composite = omp_get_wtime() - t0;
    for (size_t t = 0; t < lanes.size(); t += 2) {
        C.lanes_evaluated += lanes[t];
        C.lanes_used += lanes[t + 1];
    }
}

void backward(Context& C, const float* g_rgb, const float* g_alpha, const float* g_depth,
              float* d_means, float* d_log_scales, float* d_quats, float* d_logits,
              float* d_colors) {
    const int64_t n = C.n;
    C.entry_grad.resize(C.bins.tile_ids.size() * kEntryGrad);  // every tile writes its entries
    const double t0 = omp_get_wtime();
    for_each_tile(C, [&](const TileSplat* G, int64_t n, const TileFrame& f, int64_t s, int64_t t) {
        C.kernels.composite_backward(G, n, f, C.params.background, g_rgb, g_alpha, g_depth,
                                     C.T_final.data(), &C.step_mask[s],
                                     C.records[C.tile_thread[t]].data.data(), &C.record_start[s],
                                     &C.bins.slot_of[s], C.entry_grad.data());
    });
    const double t1 = omp_get_wtime();
    C.t_bwd_composite = t1 - t0;

    std::memset(d_means, 0, sizeof(float) * 3 * n);
    std::memset(d_log_scales, 0, sizeof(float) * 3 * n);
    std::memset(d_quats, 0, sizeof(float) * 4 * n);
    std::memset(d_logits, 0, sizeof(float) * n);
    std::memset(d_colors, 0, sizeof(float) * 3 * n);
    // Each visible Gaussian sums its own tile records (contiguous, in tile order), then its
    // projection is recomputed and differentiated L Gaussians at a time, block by block (the
    // block's sums stay in cache).
    const int64_t n_visible = int64_t(C.bins.slot_ids.size());
    const GradOut out{d_means, d_log_scales, d_quats, d_logits};
    const Gaussians g = inputs(C);
    const std::vector<float>& entry_grad = C.entry_grad;
#pragma omp parallel for num_threads(thread_count(C.params)) schedule(static)
    for (int64_t b = 0; b < n_visible; b += kProjectBlock) {
        const int64_t e = std::min(b + kProjectBlock, n_visible);
        double acc[kProjectBlock * kEntryGrad] = {};
        for (int64_t k = b; k < e; ++k) {
            double* a = &acc[(k - b) * kEntryGrad];
            for (int64_t q = C.bins.isect_start[k]; q < C.bins.isect_start[k + 1]; ++q) {
                const float* r = &entry_grad[q * kEntryGrad];
                for (int c = 0; c < kEntryGrad; ++c) a[c] += r[c];
            }
            const int32_t i = C.bins.slot_ids[k];
            for (int c = 0; c < 3; ++c) d_colors[3 * i + c] = saturate(a[6 + c]);
        }
        C.kernels.vjp_range(C.cam, g, C.bins.slot_ids.data(), acc, b, e, out);
    }
    C.t_bwd_project = omp_get_wtime() - t1;
}

}  // namespace

namespace ah {

// c^(5/12) for c in [0.0031308, 1], as training's sRGB encoding needs it: a first guess from
// c's bits (a few % off), then four steps of Newton's method on y^12 = c^5, each squaring the
// error: within 4.9 ulp of the exact value over every float of the range (torch's pow route:
// 7.3). Plain arithmetic, so that the compiler vectorizes the loop, where std::pow (a call
// per value) took 1.7 ms for a 256^2 image.
inline float srgb_root(float c) {
    constexpr int32_t kOne = 0x3f800000;  // the bits of 1.0f
    int32_t bits;
    std::memcpy(&bits, &c, sizeof bits);
    bits = kOne + int32_t(float(bits - kOne) * (5.0f / 12.0f));
    float y;
    std::memcpy(&y, &bits, sizeof y);
    const float c2 = c * c, c5 = c2 * c2 * c;
#pragma GCC unroll 4
    for (int k = 0; k < 4; ++k) {
        const float y2 = y * y, y4 = y2 * y2, y11 = y4 * y4 * y2 * y;
        y = y * (11.0f / 12.0f) + c5 / (12.0f * y11);
    }
    return y;
}

// m ? a : b by the bits: a ternary between two computed floats is control flow to GCC
// (either side might trap), which keeps the loop from vectorizing.
inline float pick(bool m, float a, float b) {
    int32_t ia, ib;
    std::memcpy(&ia, &a, sizeof ia);
    std::memcpy(&ib, &b, sizeof ib);
    const int32_t mask = -int32_t(m), bits = (ia & mask) | (ib & ~mask);
    float out;
    std::memcpy(&out, &bits, sizeof out);
    return out;
}

// torch's huber_loss of one difference, and its derivative
inline float huber(float d, float delta) {
    const float a = d < 0.0f ? -d : d;
    return pick(a < delta, 0.5f * d * d, delta * (a - 0.5f * delta));
}

inline float huber_slope(float d, float delta) {
    return pick(d <= -delta, -delta, pick(d >= delta, delta, d));
}

}  // namespace ah

extern "C" {

int32_t ah_splat_abi_version(void) { return AH_SPLAT_ABI_VERSION; }

int32_t ah_splat_select_isa(int32_t isa) {
    if (isa == AH_ISA_AUTO) isa = best_isa();
    if (!isa_supported(isa)) return -1;
    active_kernels() = kernels_for(isa);
    return isa;
}

int32_t ah_splat_isa_supported(int32_t isa) { return isa_supported(isa) ? 1 : 0; }

int32_t ah_splat_set_ellipse_steps(int32_t on) {
    const bool was = ellipse_steps();
    ellipse_steps() = on != 0;
    return was ? 1 : 0;
}

int ah_splat_project(const ah_splat_params* params, int64_t n, const float* means,
                     const float* log_scales, const float* quats, const float* opacity_logits,
                     double* means2d, float* conics, float* depths, float* opacities,
                     int32_t* radii, char* err, int32_t err_len) {
    if (!check_params(params, err, err_len)) return -1;
    const Camera cam(*params);
    std::memset(means2d, 0, sizeof(double) * 2 * n);
    std::memset(conics, 0, sizeof(float) * 3 * n);
    std::memset(depths, 0, sizeof(float) * n);
    std::memset(opacities, 0, sizeof(float) * n);
    std::memset(radii, 0, sizeof(int32_t) * 2 * n);
    const ProjectOut out{means2d, conics,  opacities, depths,  radii, nullptr,
                         nullptr, nullptr, nullptr,   nullptr, false};
    project_blocks(active_kernels(), cam, Gaussians{means, log_scales, quats, opacity_logits}, n,
                   out, thread_count(*params));
    return 0;
}

void* ah_splat_forward(const ah_splat_params* params, int64_t n, const float* means,
                       const float* log_scales, const float* quats, const float* opacity_logits,
                       const float* colors, float* out_rgb, float* out_alpha, float* out_depth,
                       char* err, int32_t err_len) {
    if (!check_params(params, err, err_len)) return nullptr;
    if (n < 0 || n > INT32_MAX) {
        set_error(err, err_len, "number of Gaussians out of range");
        return nullptr;
    }
    try {
        auto C = acquire(*params, n);
        C->means.assign(means, means + 3 * n);
        C->log_scales.assign(log_scales, log_scales + 3 * n);
        C->quats.assign(quats, quats + 4 * n);
        C->logits.assign(opacity_logits, opacity_logits + n);
        C->colors.assign(colors, colors + 3 * n);
        project_all(*C);
        render(*C, out_rgb, out_alpha, out_depth);
        return C.release();
    } catch (const std::bad_alloc&) {
        set_error(err, err_len, "out of memory in splat forward");
    } catch (const std::exception& e) {
        set_error(err, err_len, e.what());
    }
    return nullptr;
}

int ah_splat_backward(void* ctx, const float* g_rgb, const float* g_alpha, const float* g_depth,
                      float* d_means, float* d_log_scales, float* d_quats, float* d_opacity_logits,
                      float* d_colors, char* err, int32_t err_len) {
    if (!ctx || !g_rgb) {
        set_error(err, err_len, "splat backward needs a forward context and g_rgb");
        return -1;
    }
    if (!static_cast<Context*>(ctx)->recorded) {
        set_error(err, err_len, "splat backward needs a forward run with for_backward = 1");
        return -1;
    }
    try {
        backward(*static_cast<Context*>(ctx), g_rgb, g_alpha, g_depth, d_means, d_log_scales,
                 d_quats, d_opacity_logits, d_colors);
        return 0;
    } catch (const std::bad_alloc&) {
        set_error(err, err_len, "out of memory in splat backward");
    } catch (const std::exception& e) {
        set_error(err, err_len, e.what());
    }
    return -1;
}

void ah_splat_stats(const void* ctx, int64_t* stats) {
    const Context* C = static_cast<const Context*>(ctx);
    const auto ns = [](double seconds) { return int64_t(seconds * 1e9); };
    const int64_t out[AH_SPLAT_STATS_LEN] = {int64_t(C->bins.sorted.size()),
                                             int64_t(C->bins.tile_ids.size()),
                                             ns(C->t_project),
                                             ns(C->t_bin),
                                             ns(C->t_composite),
                                             ns(C->t_bwd_composite),
                                             ns(C->t_bwd_project),
                                             C->kernels.isa,
                                             C->lanes_evaluated,
                                             C->lanes_used};
    std::copy(out, out + AH_SPLAT_STATS_LEN, stats);
}

void ah_splat_release(void* ctx) { release(static_cast<Context*>(ctx)); }

int ah_mesh_rasterize(int64_t n_vertices, int64_t n_faces, const double* xy, const double* z,
                      const int64_t* faces, int32_t width, int32_t height, int64_t* face_at,
                      double* bary, char* err, int32_t err_len) {
    if (width < 0 || height < 0 || n_faces < 0) {
        set_error(err, err_len, "negative image size or face count");
        return -1;
    }
    for (int64_t i = 0; i < 3 * n_faces; ++i) {
        if (faces[i] < 0 || faces[i] >= n_vertices) {
            set_error(err, err_len, "a face's vertex index is out of range");
            return -1;
        }
    }
    try {
        ah::rasterize_mesh(n_faces, xy, z, faces, width, height, face_at, bary);
    } catch (const std::exception& e) {  // the z-buffer's allocation
        set_error(err, err_len, e.what());
        return -1;
    }
    return 0;
}

void ah_srgb_encode(int64_t n, const float* x, float* y, float* slope, int32_t num_threads) {
    // one pass, where torch's pow, where and their backward passes took 3.2 times as long
    // (benchmarks/kernel_ops.py)
    const int threads = thread_count(num_threads);
#pragma omp parallel for num_threads(threads) schedule(static) if (n >= 16384)
    for (int64_t i = 0; i < n; ++i) {
        const float v = x[i];
        const float inside = float((v > 0.0f) & (v < 1.0f));  // as torch.clamp: 0 at both ends
        const float c = ah::pick(v > 1.0f, 1.0f, ah::pick(v < 0.0f, 0.0f, v));  // NaN stays NaN
        const bool low = c <= 0.0031308f;
        const float root = ah::srgb_root(ah::pick(low, 1.0f, c));
        y[i] = ah::pick(low, 12.92f * c, 1.055f * root - 0.055f);
        slope[i] = inside * ah::pick(low, 12.92f, (1.055f / 2.4f) * root / c);
    }
}

void ah_image_huber(int64_t n_pixels, int32_t channels, const float* pred, const float* target,
                    const float* parts, float delta, double* terms, float* grad_rgb,
                    float* grad_parts, int32_t num_threads) {
    // One pass where torch took two huber_loss calls, the masked copies and their backward
    // passes (benchmarks/kernel_ops.py). Blocks of kPixels pixels: the values and
    // gradients in a loop that vectorizes (no sum in it: GCC keeps a float sum's order), then
    // each block's sums in kLanes lanes, the blocks' added in order: the same bits at any
    // thread count.
    constexpr int64_t kPixels = 1024, kLanes = 8, kMaxChannels = 4;
    if (channels < 1 || channels > kMaxChannels) {  // kernel.image_huber refuses them first
        terms[0] = terms[1] = NAN;
        return;
    }
    const int64_t n = n_pixels * channels, blocks = (n_pixels + kPixels - 1) / kPixels;
    std::vector<double> sums(2 * blocks, 0.0);
    const float scale = 1.0f / float(n);
    const int threads = thread_count(num_threads);
#pragma omp parallel for num_threads(threads) schedule(static) if (blocks > 1)
    for (int64_t k = 0; k < blocks; ++k) {
        const int64_t pixels = std::min(n_pixels - k * kPixels, kPixels);
        const int64_t first = k * kPixels * channels, count = pixels * channels;
        // whole lanes: the values past `count` stay 0
        float weight[kPixels * kMaxChannels], rgb[kPixels * kMaxChannels] = {},
                                              part[kPixels * kMaxChannels] = {};
        for (int64_t q = 0; q < pixels; ++q)
            for (int32_t c = 0; c < channels; ++c) weight[q * channels + c] = parts[k * kPixels + q];
        const float *p = pred + first, *t = target + first;
        float *g_rgb = grad_rgb + first, *g_part = grad_parts + first;
        for (int64_t i = 0; i < count; ++i) {
            const float b = weight[i], d = p[i] - t[i];
            const float db = p[i] * b - t[i] * b;  // as torch: each image masked first
            rgb[i] = ah::huber(d, delta);
            part[i] = ah::huber(db, delta);
            g_rgb[i] = ah::huber_slope(d, delta) * scale;
            g_part[i] = ah::huber_slope(db, delta) * b * scale;
        }
        double lane_rgb[kLanes] = {}, lane_part[kLanes] = {};
        for (int64_t i = 0; i < count; i += kLanes) {
            for (int64_t j = 0; j < kLanes; ++j) {
                lane_rgb[j] += rgb[i + j];
                lane_part[j] += part[i + j];
            }
        }
        for (int64_t j = 0; j < kLanes; ++j) {
            sums[2 * k] += lane_rgb[j];
            sums[2 * k + 1] += lane_part[j];
        }
    }
    double rgb = 0.0, part = 0.0;
    for (int64_t k = 0; k < blocks; ++k) {
        rgb += sums[2 * k];
        part += sums[2 * k + 1];
    }
    terms[0] = rgb / double(n);
    terms[1] = part / double(n);
}

void ah_resample_forward(int32_t c, int32_t s, const float* f, int32_t size, const int32_t* index,
                         const float* weight, float blend, int64_t n, const int64_t* texel,
                         float* out, int32_t num_threads) {
    const int threads = thread_count(num_threads);
    ah::resample_forward({c, s, size, index, weight, blend, threads}, f, n, texel, out);
}

void ah_resample_backward(int32_t c, int32_t s, int32_t size, const int32_t* index,
                          const float* weight, float blend, int64_t n, const int64_t* texel,
                          const float* grad, float* grad_f, int32_t num_threads) {
    const int threads = thread_count(num_threads);
    ah::resample_backward({c, s, size, index, weight, blend, threads}, n, texel, grad, grad_f);
}


}  // extern "C"
