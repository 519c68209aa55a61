// Run-time choice of the instruction set for the hot loops. The library is compiled for
// baseline x86-64 (no -march=native: it must load on any x86-64); the projection and the
// compositing loops are also compiled for AVX2 and AVX-512 (GCC on x86-64), and
// ah_splat_select_isa picks the best the CPU has, or the one asked for (the tests run each
// against the reference).
#pragma once

#include <cstdint>
#include <vector>

#include "raster.hpp"
#include "splat.h"

namespace ah {

typedef void (*CompositeForwardFn)(const TileSplat*, int64_t, const TileFrame&, const float*,
                                   float*, float*, float*, float*, uint64_t*, StepRecords*,
                                   int64_t*, int64_t*);
typedef void (*CompositeBackwardFn)(const TileSplat*, int64_t, const TileFrame&, const float*,
                                    const float*, const float*, const float*, const float*,
                                    const uint64_t*, const float*, const int64_t*, const int64_t*,
                                    float*);

typedef void (*ProjectRangeFn)(const Camera&, const Gaussians&, int64_t, int64_t,
                               const ProjectOut&);
typedef void (*VjpRangeFn)(const Camera&, const Gaussians&, const int32_t*, const double*, int64_t,
                           int64_t, const GradOut&);

struct Kernels {
    int32_t isa;   // AH_ISA_*
    int32_t tile;  // the compositing's tile edge in pixels
    ProjectRangeFn project_range;
    VjpRangeFn vjp_range;
    CompositeForwardFn composite_forward;
    CompositeBackwardFn composite_backward;
};

// The templates once per instruction set. Baseline (SSE2 on x86-64, or the plain build
// elsewhere) takes 128-bit vectors: 2 Gaussians, 4 pixels a step (wider GCC vectors have no
// SSE2 compares and would be split into scalar code).
namespace baseline {
#include "projection_lanes.hpp"
#include "raster_lanes.hpp"
}  // namespace baseline

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define AH_X86_DISPATCH 1
namespace avx2 {
#pragma GCC push_options
#pragma GCC target("avx2,fma")
#include "projection_lanes.hpp"
#include "raster_lanes.hpp"
#pragma GCC pop_options
}  // namespace avx2

namespace avx512 {
#pragma GCC push_options
#pragma GCC target("avx512f,avx512bw,avx512dq,avx512vl")
#include "projection_lanes.hpp"
#include "raster_lanes.hpp"
#pragma GCC pop_options
}  // namespace avx512
#endif

// Whether this CPU (and build) can run `isa`.
inline bool isa_supported(int32_t isa) {
#ifdef AH_X86_DISPATCH
    __builtin_cpu_init();  // may run before the library's constructors
#endif
    switch (isa) {
        case AH_ISA_BASELINE:
            return true;
#ifdef AH_X86_DISPATCH
        case AH_ISA_AVX2:
            return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
        case AH_ISA_AVX512:
            return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                   __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
#endif
        default:
            return false;
    }
}

// The kernels of one instruction set: its projection and its compositing.
template <class Project, class Raster>
Kernels kernels_of(int32_t isa) {
    return {isa,
            Raster::kTile,
            Project::project_range,
            Project::vjp_range,
            Raster::composite_forward,
            Raster::composite_backward};
}

inline Kernels kernels_for(int32_t isa) {
    switch (isa) {
#ifdef AH_X86_DISPATCH
        case AH_ISA_AVX512:
            return kernels_of<avx512::ProjectLanes<8>,
                              avx512::Raster<avx512::BlockSteps<4, 4, 32>>>(isa);
        case AH_ISA_AVX2:
            return kernels_of<avx2::ProjectLanes<4>, avx2::Raster<avx2::BlockSteps<4, 2, 16>>>(isa);
#endif
        default:
            return kernels_of<baseline::ProjectLanes<2>,
                              baseline::Raster<baseline::BlockSteps<4, 1, 16>>>(AH_ISA_BASELINE);
    }
}

inline int32_t best_isa() {
    for (int32_t isa : {AH_ISA_AVX512, AH_ISA_AVX2})
        if (isa_supported(isa)) return isa;
    return AH_ISA_BASELINE;
}

}  // namespace ah
