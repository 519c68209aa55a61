// Not a splat: the avatar's feature field at one resolution, one level at a time (the torch
// form is avatar/resample.py: dense matrix products that spend all but 4 of every s
// multiplications on zeros).
// A level f (c, s, s), channel-major as the model keeps it, resized bicubically to size x
// size by its four taps per output along each axis (bicubic.taps: index and weight, (size, 4)
// each, the same for rows and columns), read at distinct texels (flat row * size + column)
// into out (n, c), texel-major, scaled by the level's blend weight. Every sum runs in a fixed
// order: the same bits at any thread count.
#pragma once

#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <memory>

namespace ah {

struct ResampleLevel {
    int32_t c, s, size;
    const int32_t* index;  // (size, 4); null when s == size (the level is read as it is)
    const float* weight;   // (size, 4)
    float blend;
    int threads;
};

inline std::unique_ptr<float[]> floats(int64_t n) { return std::unique_ptr<float[]>(new float[n]); }

// Row y of a channel-major level f (c, s, s) laid out texel-major, dst (s, c): the channels of
// a texel side by side, as the taps' products read them
inline void texel_major_row(const float* f, int64_t c, int64_t s, int64_t y, float* dst) {
    for (int64_t k = 0; k < c; ++k)
        for (int64_t x = 0; x < s; ++x) dst[x * c + k] = f[(k * s + y) * s + x];
}

// and back: src (s, c) into row y of g (c, s, s)
inline void channel_major_row(const float* src, int64_t c, int64_t s, int64_t y, float* g) {
    for (int64_t k = 0; k < c; ++k)
        for (int64_t x = 0; x < s; ++x) g[(k * s + y) * s + x] = src[x * c + k];
}

// out (n, c) += blend * the level at the texels
inline void resample_forward(const ResampleLevel& L, const float* f, int64_t n,
                             const int64_t* texel, float* out) {
    const int64_t c = L.c, s = L.s, size = L.size;
    if (!L.index) {  // laid out texel-major row by row, then read a texel's row at once
        auto ft = floats(s * s * c);
#pragma omp parallel for num_threads(L.threads) schedule(static)
        for (int64_t y = 0; y < s; ++y) texel_major_row(f, c, s, y, &ft[y * s * c]);
#pragma omp parallel for num_threads(L.threads) schedule(static)
        for (int64_t i = 0; i < n; ++i) {
            const float* src = &ft[texel[i] * c];
            for (int64_t k = 0; k < c; ++k) out[i * c + k] += L.blend * src[k];
        }
        return;
    }
    // along the columns, row by row: cols (s, size, c), each source row first laid out
    // texel-major (a few tens of KB)
    auto cols = floats(s * size * c);
#pragma omp parallel num_threads(L.threads)
    {
        auto row = floats(s * c);
#pragma omp for schedule(static)
        for (int64_t y = 0; y < s; ++y) {
            texel_major_row(f, c, s, y, row.get());
            for (int64_t x = 0; x < size; ++x) {
                const int32_t* I = L.index + x * 4;
                const float* W = L.weight + x * 4;
                const float *a = &row[I[0] * c], *b = &row[I[1] * c], *d = &row[I[2] * c],
                            *e = &row[I[3] * c];
                float* dst = &cols[(y * size + x) * c];
                for (int64_t k = 0; k < c; ++k)
                    dst[k] = W[0] * a[k] + W[1] * b[k] + W[2] * d[k] + W[3] * e[k];
            }
        }
    }
    // along the rows, at the texels
#pragma omp parallel for num_threads(L.threads) schedule(static)
    for (int64_t i = 0; i < n; ++i) {
        const int64_t r = texel[i] / size, col = texel[i] % size;
        const int32_t* I = L.index + r * 4;
        const float* W = L.weight + r * 4;
        const float *a = &cols[(I[0] * size + col) * c], *b = &cols[(I[1] * size + col) * c],
                    *d = &cols[(I[2] * size + col) * c], *e = &cols[(I[3] * size + col) * c];
        float* dst = out + i * c;
        for (int64_t k = 0; k < c; ++k)
            dst[k] += L.blend * (W[0] * a[k] + W[1] * b[k] + W[2] * d[k] + W[3] * e[k]);
    }
}

// grad_f (c, s, s) = the gradient of blend * the level at the texels, given grad (n, c)
inline void resample_backward(const ResampleLevel& L, int64_t n, const int64_t* texel,
                              const float* grad, float* grad_f) {
    const int64_t c = L.c, s = L.s, size = L.size;
    if (!L.index) {
        auto gft = floats(s * s * c);
        std::fill(gft.get(), gft.get() + s * s * c, 0.0f);
#pragma omp parallel for num_threads(L.threads) schedule(static)
        for (int64_t i = 0; i < n; ++i)  // distinct texels: each row written once
            for (int64_t k = 0; k < c; ++k) gft[texel[i] * c + k] = L.blend * grad[i * c + k];
#pragma omp parallel for num_threads(L.threads) schedule(static)
        for (int64_t y = 0; y < s; ++y) channel_major_row(&gft[y * s * c], c, s, y, grad_f);
        return;
    }
    // the rows' transpose: texels that share a source row add into it, so the threads split
    // the channels (each channel's sums then run over the texels in order)
    auto cols = floats(s * size * c);
    std::fill(cols.get(), cols.get() + s * size * c, 0.0f);
    const int64_t chunk = c < 8 * L.threads ? c : (c / L.threads + 7) / 8 * 8;
#pragma omp parallel for num_threads(L.threads) schedule(static)
    for (int64_t k0 = 0; k0 < c; k0 += chunk) {
        const int64_t k1 = k0 + chunk < c ? k0 + chunk : c;
        for (int64_t i = 0; i < n; ++i) {
            const int64_t r = texel[i] / size, col = texel[i] % size;
            const float* g = grad + i * c;
            for (int t = 0; t < 4; ++t) {
                const float w = L.blend * L.weight[r * 4 + t];
                float* dst = &cols[(L.index[r * 4 + t] * size + col) * c];
                for (int64_t k = k0; k < k1; ++k) dst[k] += w * g[k];
            }
        }
    }
    // the columns' transpose, row by row (each source row y is its own), laid back out
    // channel-major
#pragma omp parallel num_threads(L.threads)
    {
        auto row = floats(s * c);
#pragma omp for schedule(static)
        for (int64_t y = 0; y < s; ++y) {
            std::fill(row.get(), row.get() + s * c, 0.0f);
            for (int64_t x = 0; x < size; ++x) {
                const float* src = &cols[(y * size + x) * c];
                for (int u = 0; u < 4; ++u) {
                    const float w = L.weight[x * 4 + u];
                    float* dst = &row[L.index[x * 4 + u] * c];
                    for (int64_t k = 0; k < c; ++k) dst[k] += w * src[k];
                }
            }
            channel_major_row(row.get(), c, s, y, grad_f);
        }
    }
}

}  // namespace ah
