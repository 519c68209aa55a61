"""Splat kernel, one scene, every version in one run:
`python benchmarks/splat_versions.py [--before REV] [--opensplat DIR] [--gaussians N]
[--size S] [--quick]`.

The face-like scene (`scenes.face_scene`) at 60k Gaussians, 512² (or N, S²), one thread.
Rows, each the best of --repeats forward and backward passes (wall clock around the call):
- the kernel of git revision --before (default c8a0463: the float64 scalar projection,
  recomputed in the backward, and AVX2 compositing, the reference for the figures in
  docs/bench_splat.md), compiled from `git show` into a temporary folder;
- this tree's kernel on each compositing path the CPU runs (kernel.set_simd), with its
  phase split (stats(): projection, sort and binning, compositing; backward compositing,
  backward per-Gaussian reduction and projection VJP), and its forward on the best path for
  an image alone (`for_backward=False`, without the records the backward reads);
- OpenSplat's CPU rasterizer (`rasterizer/gsplat-cpu`, single-threaded), when --opensplat
  (or $ARCHHEAD_OPENSPLAT) names a checkout of github.com/pierotofy/OpenSplat: compiled here
  as a torch extension from that folder (AGPL, never copied into this repository), fed this
  kernel's projection (means2d, conics, opacities, depths), and timed on its rasterize
  forward and backward only, so its projection and projection VJP are free;
and ratios to this tree's best path, all from this run.

Vector limit: the forward compositing loop's pixel-lane rate (lanes evaluated per second,
in forwards for an image alone: the loop without the backward's records) on ideal data,
where every lane evaluated composites a sample (`ideal_scene`: large low-opacity Gaussians
covering the whole image). On the real scene the benchmark prints the lanes used (that
composited a sample) per second of compositing as a share of that limit, and the share of
evaluated lanes that were used.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import subprocess
import tempfile
from functools import partial
from pathlib import Path

import numpy as np
from splat_kernel import machine  # this script's folder is on sys.path

from archhead_addon.splat import build, kernel, scenes
from archhead_addon.splat.frame import SplatFrame
from archhead_addon.timing import time_calls

BEFORE = "c8a0463"
N, SIZE = 60_000, 512
PHASES = ("project_ms", "bin_ms", "composite_ms", "bwd_composite_ms", "bwd_project_ms")


def once_ms(fn) -> float:
    return time_calls(fn, 1).min_ms


class Current:
    """This tree's kernel on one compositing path (kernel.set_simd)."""

    def __init__(self, scene: scenes.Scene, simd: str):
        self.simd = simd
        self.g, self.settings = scene.gaussians.checked(), scene.settings(num_threads=1)
        self.g_rgb = np.full((scene.height, scene.width, 3), 0.1, np.float32)

    def sample(self) -> dict:
        """One forward's and one backward's ms, and the stats() of that pair."""
        kernel.set_simd(self.simd)
        out = []
        fwd = once_ms(lambda: out.append(kernel.forward(self.g, self.settings)))
        ctx = out[0][1]
        bwd = once_ms(lambda: kernel.backward(ctx, self.g_rgb))
        return {"fwd": fwd, "bwd": bwd, **ctx.stats()}


class ImageOnly(Current):
    """This tree's forward for an image alone (`for_backward=False`: no step records)."""

    def sample(self) -> dict:
        kernel.set_simd(self.simd)
        out = []
        fwd = once_ms(lambda: out.append(kernel.forward(self.g, self.settings, False)))
        return {"fwd": fwd, **out[0][1].stats()}


class Before:
    """The kernel of a git revision, compiled from its sources, called through ctypes (the
    forward / backward ABI has not changed since ABI version 1)."""

    def __init__(self, rev: str, folder: Path, scene: scenes.Scene):
        root = Path(__file__).resolve().parents[1]
        csrc = "archhead_addon/splat/csrc"
        names = subprocess.run(
            ["git", "ls-tree", "--name-only", f"{rev}:{csrc}"], cwd=root, check=True,
            capture_output=True, text=True,
        ).stdout.split()  # fmt: skip
        for name in names:
            text = subprocess.run(["git", "show", f"{rev}:{csrc}/{name}"], cwd=root, check=True,
                                  capture_output=True).stdout  # fmt: skip
            (folder / name).write_bytes(text)
        lib_path = folder / "libbefore.so"
        subprocess.run([build.find_compiler(), *build.FLAGS, str(folder / "splat.cpp"), "-o",
                        str(lib_path)], check=True)  # fmt: skip
        self.lib = lib = ctypes.CDLL(str(lib_path))
        ptr = ctypes.POINTER(ctypes.c_float)
        lib.ah_splat_forward.argtypes = [ctypes.c_void_p, ctypes.c_int64, *[ptr] * 8,
                                         ctypes.c_char_p, ctypes.c_int32]  # fmt: skip
        lib.ah_splat_forward.restype = ctypes.c_void_p
        lib.ah_splat_backward.argtypes = [ctypes.c_void_p, *[ptr] * 8, ctypes.c_char_p,
                                          ctypes.c_int32]  # fmt: skip
        lib.ah_splat_release.argtypes = [ctypes.c_void_p]
        self.g, self.params = scene.gaussians.checked(), scene.settings(num_threads=1).to_c()
        h, w = scene.height, scene.width
        self.out = [np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32),
                    np.empty((h, w), np.float32)]  # fmt: skip
        self.grads = SplatFrame(*(np.empty_like(a) for a in self.g.arrays().values()))
        self.g_rgb = np.full((h, w, 3), 0.1, np.float32)
        self.err = ctypes.create_string_buffer(512)

    def sample(self) -> dict:
        p, err = _pointers, self.err
        args = (ctypes.byref(self.params), len(self.g), *p(self.g), *p(self.out), err, 512)
        ctxs = []
        fwd = once_ms(lambda: ctxs.append(self.lib.ah_splat_forward(*args)))
        grads = (*p([self.g_rgb]), None, None, *p(self.grads), err, 512)
        bwd = once_ms(lambda: self.lib.ah_splat_backward(ctxs[0], *grads))
        self.lib.ah_splat_release(ctxs[0])
        return {"fwd": fwd, "bwd": bwd}


def _pointers(arrays) -> list:
    if isinstance(arrays, SplatFrame):
        arrays = arrays.arrays().values()
    return [a.ctypes.data_as(ctypes.POINTER(ctypes.c_float)) for a in arrays]


def interleaved(samplers: dict, repeats: int) -> dict[str, dict]:
    """Each version's best of `repeats` samples (each figure its own minimum), taken in
    rounds of one sample per version so that changing load on the machine hits all alike."""
    best: dict[str, dict] = {name: {} for name in samplers}
    for _ in range(repeats):
        for name, sampler in samplers.items():
            for key, value in sampler.sample().items():
                old = best[name].get(key, value)
                best[name][key] = min(old, value) if isinstance(value, float) else value
    return best


# Glue around OpenSplat's rasterizer (this project's code, compiled with it at run time).
_OPENSPLAT_GLUE = r"""
#include <torch/extension.h>
#include "bindings.h"

std::tuple<torch::Tensor, torch::Tensor, int64_t> forward(
    int w, int h, torch::Tensor xys, torch::Tensor conics, torch::Tensor colors,
    torch::Tensor opacities, torch::Tensor bg, torch::Tensor cov2d, torch::Tensor depths) {
    auto r = rasterize_forward_tensor_cpu(w, h, xys, conics, colors, opacities, bg, cov2d,
                                          depths);
    return {std::get<0>(r), std::get<1>(r), reinterpret_cast<int64_t>(std::get<2>(r))};
}

std::vector<torch::Tensor> backward(
    int h, int w, torch::Tensor xys, torch::Tensor conics, torch::Tensor colors,
    torch::Tensor opacities, torch::Tensor bg, torch::Tensor cov2d, torch::Tensor depths,
    torch::Tensor final_Ts, int64_t px2gid, torch::Tensor v_out, torch::Tensor v_alpha) {
    auto r = rasterize_backward_tensor_cpu(h, w, xys, conics, colors, opacities, bg, cov2d,
        depths, final_Ts, reinterpret_cast<std::vector<int32_t>*>(px2gid), v_out, v_alpha);
    return {std::get<0>(r), std::get<1>(r), std::get<2>(r), std::get<3>(r)};
}

void release(int64_t px2gid) { delete[] reinterpret_cast<std::vector<int32_t>*>(px2gid); }

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    m.def("forward", &forward);
    m.def("backward", &backward);
    m.def("release", &release);
}
"""


def opensplat_module(checkout: Path):
    """OpenSplat's CPU rasterizer as a torch extension, built in the cache (minutes, once)."""
    from torch.utils.cpp_extension import load

    from archhead_addon.paths import cache_dir

    cpu = checkout / "rasterizer" / "gsplat-cpu"
    folder = cache_dir() / "opensplat_build"
    folder.mkdir(parents=True, exist_ok=True)
    glue = folder / "glue.cpp"
    if not glue.exists() or glue.read_text() != _OPENSPLAT_GLUE:
        glue.write_text(_OPENSPLAT_GLUE)
    return load("opensplat_cpu", [str(glue), str(cpu / "gsplat_cpu.cpp")],
                extra_include_paths=[str(cpu)], extra_cflags=["-O3"], build_directory=str(folder),
                verbose=False)  # fmt: skip


class OpenSplat:
    """OpenSplat's CPU rasterizer fed this kernel's projection of the scene."""

    def __init__(self, module, scene: scenes.Scene):
        import torch

        torch.set_num_threads(1)
        proj = kernel.project(scene.gaussians.checked(), scene.settings(num_threads=1))
        keep = proj.radii[:, 0] > 0
        t = lambda a: torch.tensor(np.ascontiguousarray(a), dtype=torch.float32)  # noqa: E731
        a, b, c = proj.conics[keep].astype(np.float64).T
        det = a * c - b * b
        cov2d = np.stack([np.stack([c, -b], -1), np.stack([-b, a], -1)], -2) / det[:, None, None]
        # OpenSplat's falloff is 0.5 (A x² + C y²) + B x y: its B is our b.
        self.args = (
            t(proj.means2d[keep]), t(proj.conics[keep]), t(scene.gaussians.sh[keep]),
            t(proj.opacities[keep][:, None]), t(np.zeros(3)), t(cov2d), t(proj.depths[keep]),
        )  # fmt: skip
        self.module, self.h, self.w = module, scene.height, scene.width
        self.v_out, self.v_alpha = torch.full((self.h, self.w, 3), 0.1), torch.zeros(self.h, self.w)

    def sample(self) -> dict:
        h, w, m = self.h, self.w, self.module
        out = []
        fwd = once_ms(lambda: out.append(m.forward(w, h, *self.args)))
        _, final_ts, px2gid = out[0]
        bwd = once_ms(partial(m.backward, h, w, *self.args, final_ts, px2gid, self.v_out,
                              self.v_alpha))  # fmt: skip
        m.release(px2gid)
        return {"fwd": fwd, "bwd": bwd}


def ideal_scene(width: int, height: int, n: int = 64) -> scenes.Scene:
    """Gaussians far wider than the image, opacity 0.05 (T stays above 1e-4 after n = 64):
    every lane the compositing evaluates composites a sample."""
    scene = scenes.random_scene(n, width, height, seed=0)
    g = scene.gaussians
    focal = scene.K[0, 0]
    means = np.stack([np.full(n, 0.0), np.zeros(n), np.linspace(1.0, 2.0, n)], -1)
    log_scales = np.log(means[:, 2:3] * 10 * max(width, height) / focal) * np.ones((1, 3))
    logit = np.full(n, np.log(0.05 / 0.95))
    ideal = SplatFrame(means=means, log_scales=log_scales, quats=g.quats, opacity_logits=logit,
                       sh=g.sh)  # fmt: skip
    return scene._replace(gaussians=ideal.map(lambda a: np.asarray(a, np.float32)))


def report(args) -> str:
    n, size = (3_000, 128) if args.quick else (args.gaussians, args.size)
    scene = scenes.face_scene(n, size, size, seed=0)
    paths = kernel.supported_simd()
    samplers: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        if args.before != "none":
            samplers[f"before ({args.before})"] = Before(args.before, Path(tmp), scene)
        for name in paths:
            samplers[f"now, {name}"] = Current(scene, name)
        samplers[f"now, {paths[-1]}, image only"] = ImageOnly(scene, paths[-1])
        checkout = args.opensplat or os.environ.get("ARCHHEAD_OPENSPLAT")
        note = "OpenSplat: skipped (no --opensplat checkout)"
        if checkout and (Path(checkout) / "rasterizer" / "gsplat-cpu").is_dir():
            samplers["OpenSplat CPU rasterizer"] = OpenSplat(opensplat_module(Path(checkout)),
                                                             scene)  # fmt: skip
            note = f"OpenSplat: {checkout}"
        elif checkout:
            note = f"OpenSplat: skipped ({checkout} has no rasterizer/gsplat-cpu)"
        rows = interleaved(samplers, args.repeats)
        lanes = lane_table(scene, paths, args.repeats)
    kernel.set_simd("auto")

    best = f"now, {paths[-1]}"
    lines = [
        f"face_scene({n:,}) at {size}², 1 thread, best of {args.repeats} (interleaved); "
        f"ratios: row / '{best}' (this tree's best path). {note}.",
        "",
        "| version | fwd ms | bwd ms | fwd ratio | bwd ratio | projection | sort+bin "
        "| compositing | bwd compositing | bwd reduce+VJP |",
        "|" + "---|" * 10,
    ]
    for label, r in rows.items():
        split = [f"{r[k]:.1f}" if k in r and r[k] else "" for k in PHASES]
        bwd = (f"{r['bwd']:.1f}", f"{r['bwd'] / rows[best]['bwd']:.2f}") if "bwd" in r else ("", "")
        lines.append(
            f"| {label} | {r['fwd']:.1f} | {bwd[0]} | {r['fwd'] / rows[best]['fwd']:.2f} "
            f"| {bwd[1]} | " + " | ".join(split) + " |"
        )
    return "\n".join([*lines, "", lanes])


def lane_table(scene: scenes.Scene, paths: list[str], repeats: int) -> str:
    """Per path: the vector limit (lanes/s on ideal data) and the real scene's lane rates."""
    ideal = ideal_scene(scene.width, scene.height)
    samplers = {}
    for name in paths:
        samplers[("ideal", name)] = ImageOnly(ideal, name)
        samplers[("real", name)] = ImageOnly(scene, name)
    best = interleaved(samplers, repeats)
    rate = lambda r, key: r[key] / (r["composite_ms"] * 1e-3)  # noqa: E731
    out = ["| path | limit: lanes/s on ideal data | evaluated lanes/s | used lanes/s "
           "| used / limit | used / evaluated |", "|" + "---|" * 6]  # fmt: skip
    for name in paths:
        ideal_r, real = best[("ideal", name)], best[("real", name)]
        assert ideal_r["lanes_used"] == ideal_r["lanes_evaluated"], "ideal data wastes lanes"
        limit = rate(ideal_r, "lanes_evaluated")
        evaluated, used = rate(real, "lanes_evaluated"), rate(real, "lanes_used")
        out.append(
            f"| {name} | {limit / 1e6:,.0f} M | {evaluated / 1e6:,.0f} M | {used / 1e6:,.0f} M "
            f"| {used / limit:.0%} | {used / evaluated:.0%} |"
        )
    return "\n".join(out)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default=BEFORE, help="git revision, or 'none' to skip")
    parser.add_argument("--opensplat", help="OpenSplat checkout (default $ARCHHEAD_OPENSPLAT)")
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--gaussians", type=int, default=N, help=f"default {N:,}")
    parser.add_argument("--size", type=int, default=SIZE, help=f"image side, default {SIZE}")
    parser.add_argument("--quick", action="store_true", help="3k Gaussians at 128²")
    args = parser.parse_args(argv)
    print(report(args))
    print("\n" + machine())


if __name__ == "__main__":
    main()
