"""ctypes binding of the C++ splat kernel. numpy only: Blender's Python uses it directly.

Gaussians come as a `SplatFrame` (frame.py; its fields by name, in the C ABI's order):
  means (N,3) world positions; log_scales (N,3) natural log of the axis scales (clamped to
  [-23, 11.5] before exp); quats (N,4) w,x,y,z (normalised inside, zero -> identity);
  opacity_logits (N,) (opacity = sigmoid); sh (N,3) RGB after SH evaluation (`render_frame`
  also takes (N,K,3) SH coefficients and evaluates them towards the camera).
  viewmat (4,4) world-to-camera, OpenCV axes (x right, y down, z forward); K (3,3) in
  pixels, pixel (i, j) centred at (i + 0.5, j + 0.5).
Every input must be finite; a non-finite entry raises ValueError naming the array.

The hot loops run with the best instruction set the CPU has (AVX-512, AVX2, baseline
x86-64); `set_simd` or the environment variable ARCHHEAD_SPLAT_SIMD (read when the library
loads) forces one, e.g. to test each against the reference.
"""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..camera import affine_inverse
from ..threads import thread_count
from . import build
from .frame import SplatFrame, check_array, from_gsplat_order
from .sh import degree_from_coeffs, sh_to_rgb_numpy

LOG_SCALE_MIN, LOG_SCALE_MAX = -23.0, 11.5  # AH_LOG_SCALE_MIN/MAX in csrc/splat.h
_ERR_LEN = 512
_F32 = ctypes.POINTER(ctypes.c_float)


class KernelNotBuiltError(RuntimeError):
    """The shared library is not built for these sources and cannot be compiled here."""


class _Params(ctypes.Structure):
    _fields_ = [
        ("width", ctypes.c_int32),
        ("height", ctypes.c_int32),
        ("viewmat", ctypes.c_double * 16),
        ("K", ctypes.c_double * 9),
        ("near_plane", ctypes.c_float),
        ("far_plane", ctypes.c_float),
        ("eps2d", ctypes.c_float),
        ("antialiased", ctypes.c_int32),
        ("background", ctypes.c_float * 3),
        ("num_threads", ctypes.c_int32),
        ("for_backward", ctypes.c_int32),
    ]


_ABI_VERSION = 5
_lib: ctypes.CDLL | None = None
SIMD = {"auto": -1, "baseline": 0, "avx2": 1, "avx512": 2}  # AH_ISA_* in csrc/splat.h
SIMD_ENV = "ARCHHEAD_SPLAT_SIMD"


def library() -> ctypes.CDLL:
    """The loaded kernel, compiled on first use where needed (build.ensure_library); raises
    KernelNotBuiltError saying what to install when it cannot be."""
    global _lib
    if _lib is not None:
        return _lib
    try:
        path = build.ensure_library()
    except build.BuildError as exc:
        raise KernelNotBuiltError(f"The splat kernel could not be compiled: {exc}") from exc
    lib = ctypes.CDLL(str(path))
    if lib.ah_splat_abi_version() != _ABI_VERSION:
        raise KernelNotBuiltError("The splat kernel's ABI version does not match: rebuild it.")
    P, i64, i32, cp = ctypes.POINTER(_Params), ctypes.c_int64, ctypes.c_int32, ctypes.c_char_p
    f64, ip = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int32)
    lib.ah_splat_project.argtypes = [
        P,
        i64,
        _F32,
        _F32,
        _F32,
        _F32,
        f64,
        _F32,
        _F32,
        _F32,
        ip,
        cp,
        i32,
    ]
    lib.ah_splat_project.restype = ctypes.c_int
    lib.ah_splat_forward.argtypes = [
        P,
        i64,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        cp,
        i32,
    ]
    lib.ah_splat_forward.restype = ctypes.c_void_p
    lib.ah_splat_backward.argtypes = [
        ctypes.c_void_p,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        _F32,
        cp,
        i32,
    ]
    lib.ah_splat_backward.restype = ctypes.c_int
    lib.ah_splat_stats.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int64)]
    lib.ah_splat_stats.restype = None
    lib.ah_splat_release.argtypes = [ctypes.c_void_p]
    lib.ah_splat_release.restype = None
    lib.ah_splat_select_isa.argtypes = [i32]
    lib.ah_splat_select_isa.restype = i32
    lib.ah_splat_isa_supported.argtypes = [i32]
    lib.ah_splat_isa_supported.restype = i32
    lib.ah_splat_set_ellipse_steps.argtypes = [i32]
    lib.ah_splat_set_ellipse_steps.restype = i32
    i64p = ctypes.POINTER(ctypes.c_int64)
    lib.ah_mesh_rasterize.argtypes = [i64, i64, f64, f64, i64p, i32, i32, i64p, f64, cp, i32]
    lib.ah_mesh_rasterize.restype = ctypes.c_int
    lib.ah_srgb_encode.argtypes = [i64, _F32, _F32, _F32, i32]
    lib.ah_srgb_encode.restype = None
    lib.ah_image_huber.argtypes = [i64, i32, _F32, _F32, _F32, ctypes.c_float, f64, _F32, _F32, i32]
    lib.ah_image_huber.restype = None
    i32p, fl = ctypes.POINTER(ctypes.c_int32), ctypes.c_float
    lib.ah_resample_forward.argtypes = [i32, i32, _F32, i32, i32p, _F32, fl, i64, i64p, _F32, i32]
    lib.ah_resample_forward.restype = None
    lib.ah_resample_backward.argtypes = [i32, i32, i32, i32p, _F32, fl, i64, i64p, _F32, _F32, i32]
    lib.ah_resample_backward.restype = None
    _lib = lib
    set_simd(os.environ.get(SIMD_ENV, "auto"))
    return lib


def set_simd(name: str) -> str:
    """Run the following forward passes (and their backward passes) with the instruction set
    `name` (a key of SIMD; "auto": the best the CPU has) and return the one chosen. Raises
    ValueError for an unknown name or one this CPU cannot run."""
    if name not in SIMD:
        raise ValueError(f"unknown splat SIMD {name!r} (from {SIMD_ENV}?): one of {list(SIMD)}")
    isa = library().ah_splat_select_isa(SIMD[name])
    if isa < 0:
        raise ValueError(f"this CPU cannot run the splat kernel's {name} path")
    return next(k for k, v in SIMD.items() if v == isa)


def set_ellipse_steps(on: bool) -> bool:
    """Whether the following forward passes (and their backward passes) skip the compositing
    steps outside each Gaussian's ellipse (the default) or take every step of its box: the
    images and gradients are the same, only the work differs (for tests and benchmarks).
    Returns the previous setting."""
    return bool(library().ah_splat_set_ellipse_steps(int(on)))


def supported_simd() -> list[str]:
    """The instruction sets (keys of SIMD but "auto") this CPU runs, best last."""
    return [
        name for name, isa in SIMD.items() if isa >= 0 and library().ah_splat_isa_supported(isa)
    ]


@dataclass(frozen=True)
class RasterSettings:
    """Camera and compositing settings of one render."""

    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int
    near_plane: float = 0.01
    far_plane: float = 1e10
    eps2d: float = 0.3
    antialiased: bool = False
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    num_threads: int = 0  # 0: OMP_NUM_THREADS or every core; clamped to the cores (threads.py)

    def to_c(self) -> _Params:
        viewmat = check_array("viewmat", self.viewmat, (4, 4), np.float64)
        K = check_array("K", self.K, (3, 3), np.float64)
        background = check_array("background", self.background, (3,))
        p = _Params()
        p.width, p.height = int(self.width), int(self.height)
        p.viewmat[:] = viewmat.ravel().tolist()
        p.K[:] = K.ravel().tolist()
        p.near_plane, p.far_plane = float(self.near_plane), float(self.far_plane)
        p.eps2d = float(self.eps2d)
        p.antialiased = int(bool(self.antialiased))
        p.background[:] = background.tolist()
        p.num_threads = thread_count(self.num_threads, None, "num_threads")
        p.for_backward = 1
        return p


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(_F32)


def _require_checked(g: SplatFrame) -> int:
    """N, after a cheap check that the frame went through `SplatFrame.checked()` with RGB
    colours: the kernel reads the arrays through raw pointers."""
    n = len(g.means)
    shapes = {"means": (n, 3), "log_scales": (n, 3), "quats": (n, 4), "opacity_logits": (n,),
              "sh": (n, 3)}  # fmt: skip
    for name, a in g.arrays().items():
        if not (
            isinstance(a, np.ndarray)
            and a.dtype == np.float32
            and a.flags.c_contiguous
            and a.shape == shapes[name]
        ):
            raise ValueError(
                f"{name}: the kernel takes a checked frame (SplatFrame.checked()) with "
                f"(N,3) RGB in sh; got {getattr(a, 'dtype', type(a))} {getattr(a, 'shape', '')}"
            )
    return n


class Projected(NamedTuple):
    means2d: np.ndarray  # (N,2) float64
    conics: np.ndarray  # (N,3)
    depths: np.ndarray  # (N,)
    opacities: np.ndarray  # (N,) sigmoid(logit) (times the AA compensation)
    radii: np.ndarray  # (N,2) int32, 0 when culled


def _raise(err: ctypes.Array) -> None:
    raise ValueError(err.value.decode(errors="replace"))


def project(g: SplatFrame, settings: RasterSettings) -> Projected:
    """Per-Gaussian projection exactly as the rasteriser uses it (g: a checked frame)."""
    n = _require_checked(g)
    lib = library()
    out = Projected(
        np.zeros((n, 2), np.float64),
        np.zeros((n, 3), np.float32),
        np.zeros(n, np.float32),
        np.zeros(n, np.float32),
        np.zeros((n, 2), np.int32),
    )
    err = ctypes.create_string_buffer(_ERR_LEN)
    params = settings.to_c()
    rc = lib.ah_splat_project(
        ctypes.byref(params), n, _ptr(g.means), _ptr(g.log_scales), _ptr(g.quats),
        _ptr(g.opacity_logits), out.means2d.ctypes.data_as(ctypes.POINTER(ctypes.c_double)),
        _ptr(out.conics), _ptr(out.depths), _ptr(out.opacities),
        out.radii.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)), err, _ERR_LEN,
    )  # fmt: skip
    if rc != 0:
        _raise(err)
    return out


def rasterize_mesh(
    xy: np.ndarray, z: np.ndarray, faces: np.ndarray, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest of `faces` at each pixel centre of an image of `size` (H, W): its row in
    `faces` (H,W) int64, -1 where none, and its perspective-correct barycentrics (H,W,3)
    float64. `xy` (V,2) projected vertices in pixels, `z` (V,) their camera depths, every
    face's vertices in front of the camera; ties go to the earlier face."""
    height, width = size
    xy = np.ascontiguousarray(xy, np.float64)
    z = np.ascontiguousarray(z, np.float64)
    faces = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    if xy.shape != (len(z), 2):
        raise ValueError(f"xy: expected ({len(z)}, 2) for {len(z)} depths, got {xy.shape}")
    face_at = np.empty((height, width), np.int64)
    bary = np.empty((height, width, 3), np.float64)
    f64p, i64p = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int64)
    err = ctypes.create_string_buffer(_ERR_LEN)
    rc = library().ah_mesh_rasterize(
        len(z), len(faces), xy.ctypes.data_as(f64p), z.ctypes.data_as(f64p),
        faces.ctypes.data_as(i64p), width, height, face_at.ctypes.data_as(i64p),
        bary.ctypes.data_as(f64p), err, _ERR_LEN,
    )  # fmt: skip
    if rc != 0:
        _raise(err)
    return face_at, bary


def srgb_encode(x: np.ndarray, num_threads: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(y, dy/dx) of colour_space.linear_to_srgb on float32 `x`, each of its shape, in one
    pass (the derivative 0 where x lies outside (0, 1), as torch.clamp's)."""
    x = np.ascontiguousarray(x, np.float32)
    y, slope = np.empty_like(x), np.empty_like(x)
    threads = thread_count(num_threads, None, "num_threads")
    library().ah_srgb_encode(x.size, _ptr(x), _ptr(y), _ptr(slope), threads)
    return y, slope


def image_huber(
    pred: np.ndarray, target: np.ndarray, parts: np.ndarray, delta: float, num_threads: int = 0
) -> tuple[tuple[float, float], np.ndarray, np.ndarray]:
    """Training's two image terms (train/losses.py) in one pass: ((Huber(pred, target),
    Huber(pred B, target B)), the gradient of each with respect to `pred`). pred and target
    (H,W,C) float32, parts B (H,W)."""
    pred = np.ascontiguousarray(pred, np.float32)
    target = np.ascontiguousarray(target, np.float32)
    parts = np.ascontiguousarray(parts, np.float32)
    shapes_fit = pred.ndim == 3 and target.shape == pred.shape and parts.shape == pred.shape[:2]
    if not (shapes_fit and 1 <= pred.shape[2] <= 4):
        raise ValueError(
            f"image_huber: pred and target (H,W,C), C 1-4, and parts (H,W), got {pred.shape}, "
            f"{target.shape}, {parts.shape}"
        )
    terms = np.zeros(2, np.float64)
    g_rgb, g_parts = np.empty_like(pred), np.empty_like(pred)
    threads = thread_count(num_threads, None, "num_threads")
    library().ah_image_huber(
        parts.size, pred.shape[2], _ptr(pred), _ptr(target), _ptr(parts), delta,
        terms.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), _ptr(g_rgb), _ptr(g_parts),
        threads,
    )  # fmt: skip
    return (float(terms[0]), float(terms[1])), g_rgb, g_parts


class _Resample(NamedTuple):
    c: int
    s: int
    taps: tuple  # (int32 index, float32 weight) pointers, or (None, None) at s == size
    texel: np.ndarray
    keep: tuple  # the arrays the pointers point into


def _resample_args(f_shape, size: int, taps, texel) -> _Resample:
    """Checked arguments of the resample: the kernel reads them through raw pointers."""
    if len(f_shape) != 3 or f_shape[1] != f_shape[2]:
        raise ValueError(f"resample: a level is (C, s, s), got {f_shape}")
    c, s = f_shape[0], f_shape[1]
    texel = np.ascontiguousarray(texel, np.int64)
    if texel.ndim != 1 or (len(texel) and not 0 <= texel.min() <= texel.max() < size * size):
        raise ValueError(f"resample: texels (N,) in [0, {size * size}), got {texel.shape}")
    if (taps is None) != (s == size):
        raise ValueError(f"resample: taps for s {s} != size {size}, none at s == size")
    if taps is None:
        return _Resample(c, s, (None, None), texel, ())
    index = np.ascontiguousarray(taps[0], np.int32)
    weight = np.ascontiguousarray(taps[1], np.float32)
    if (
        index.shape != (size, 4)
        or weight.shape != (size, 4)
        or not 0 <= index.min() <= index.max() < s
    ):
        raise ValueError(f"resample: taps (size, 4) into [0, {s}), got {index.shape}")
    pointers = (index.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)), _ptr(weight))
    return _Resample(c, s, pointers, texel, (index, weight))


def resample_forward(f, size, taps, blend, texel, out, num_threads=0) -> None:
    """out (N, C) float32 += blend * level `f` (C, s, s) resized to size x size and read at
    `texel` (N,), distinct flat indices; `taps` bicubic.taps(s, size), None when s == size.
    csrc/resample.hpp."""
    f = np.ascontiguousarray(f, np.float32)
    a = _resample_args(f.shape, size, taps, texel)
    if not (
        out.dtype == np.float32 and out.flags.c_contiguous and out.shape == (len(a.texel), a.c)
    ):
        raise ValueError(f"resample: out must be contiguous float32 ({len(a.texel)}, {a.c})")
    library().ah_resample_forward(
        a.c, a.s, _ptr(f), size, *a.taps, blend, len(a.texel),
        a.texel.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)), _ptr(out),
        thread_count(num_threads, None, "num_threads"),
    )  # fmt: skip


def resample_backward(f_shape, size, taps, blend, texel, grad, num_threads=0) -> np.ndarray:
    """The gradient (C, s, s) of `resample_forward`'s output with respect to its level,
    given grad (N, C)."""
    a = _resample_args(f_shape, size, taps, texel)
    grad = np.ascontiguousarray(grad, np.float32)
    if grad.shape != (len(a.texel), a.c):
        raise ValueError(f"resample: grad must be ({len(a.texel)}, {a.c}), got {grad.shape}")
    grad_f = np.empty((a.c, a.s, a.s), np.float32)
    library().ah_resample_backward(
        a.c, a.s, size, *a.taps, blend, len(a.texel),
        a.texel.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)), _ptr(grad), _ptr(grad_f),
        thread_count(num_threads, None, "num_threads"),
    )  # fmt: skip
    return grad_f


_STATS = ("visible", "intersections", "project_ms", "bin_ms", "composite_ms", "bwd_composite_ms",
          "bwd_project_ms", "simd", "lanes_evaluated", "lanes_used")  # fmt: skip


class ForwardContext:
    """Owns the kernel state a backward pass needs; freed with the object."""

    def __init__(self, handle: int, n: int, shape: tuple[int, int]):
        self._handle = handle
        self.n = n
        self.shape = shape

    @property
    def handle(self) -> int:
        if not self._handle:
            raise RuntimeError("the splat forward context was released")
        return self._handle

    def stats(self) -> dict[str, float]:
        """Counts (visible Gaussians, tile intersections) and the last forward's and
        backward's phase times in ms (projection, sort and binning, compositing; backward
        compositing, backward per-Gaussian reduction and projection VJP), the SIMD path (a
        key of SIMD) the forward ran, and its compositing's pixel lanes: evaluated, and used
        (those that composited a sample)."""
        out = (ctypes.c_int64 * len(_STATS))()
        library().ah_splat_stats(self.handle, out)
        stats = dict(zip(_STATS, out, strict=True))
        for name in _STATS:
            if name.endswith("_ms"):
                stats[name] *= 1e-6
        stats["simd"] = next(k for k, v in SIMD.items() if v == stats["simd"])
        return stats

    def release(self) -> None:
        if self._handle and _lib is not None:
            _lib.ah_splat_release(self._handle)
        self._handle = 0

    def __del__(self):
        self.release()


class Raster(NamedTuple):
    """One image. depth: from `forward`, the accumulated sum_i w_i z_i; from `render`, the
    expected depth (that sum divided by alpha)."""

    rgb: np.ndarray  # (H,W,3) over the background
    alpha: np.ndarray  # (H,W)
    depth: np.ndarray  # (H,W)


def forward(
    g: SplatFrame, settings: RasterSettings, for_backward: bool = True
) -> tuple[Raster, ForwardContext]:
    """The image of a checked frame (`SplatFrame.checked()`, RGB in sh) and the state its
    backward pass needs (for_backward=False: the image alone, about 5 % faster; `backward`
    then raises ValueError)."""
    n = _require_checked(g)
    lib = library()
    h, w = int(settings.height), int(settings.width)
    out = Raster(
        np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32),
        np.empty((h, w), np.float32),
    )  # fmt: skip
    err = ctypes.create_string_buffer(_ERR_LEN)
    params = settings.to_c()
    params.for_backward = int(for_backward)
    handle = lib.ah_splat_forward(
        ctypes.byref(params), n, _ptr(g.means), _ptr(g.log_scales), _ptr(g.quats),
        _ptr(g.opacity_logits), _ptr(g.sh), _ptr(out.rgb), _ptr(out.alpha),
        _ptr(out.depth), err, _ERR_LEN,
    )  # fmt: skip
    if not handle:
        _raise(err)
    return out, ForwardContext(handle, n, (h, w))


def backward(ctx: ForwardContext, g_rgb, g_alpha=None, g_depth=None) -> SplatFrame:
    """Gradients of the inputs given dL/d(rgb, alpha, accumulated depth), field by field
    (sh: of the RGB colours)."""
    h, w = ctx.shape
    g_rgb = check_array("g_rgb", g_rgb, (h, w, 3))
    g_alpha = None if g_alpha is None else check_array("g_alpha", g_alpha, (h, w))
    g_depth = None if g_depth is None else check_array("g_depth", g_depth, (h, w))
    n = ctx.n
    out = SplatFrame(
        means=np.empty((n, 3), np.float32), log_scales=np.empty((n, 3), np.float32),
        quats=np.empty((n, 4), np.float32), opacity_logits=np.empty(n, np.float32),
        sh=np.empty((n, 3), np.float32),
    )  # fmt: skip
    err = ctypes.create_string_buffer(_ERR_LEN)
    rc = library().ah_splat_backward(
        ctx.handle, _ptr(g_rgb), None if g_alpha is None else _ptr(g_alpha),
        None if g_depth is None else _ptr(g_depth), _ptr(out.means), _ptr(out.log_scales),
        _ptr(out.quats), _ptr(out.opacity_logits), _ptr(out.sh), err, _ERR_LEN,
    )  # fmt: skip
    if rc != 0:
        _raise(err)
    return out


def expected_depth(depth_acc: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Accumulated depth divided by alpha (gsplat's "ED"); 0 where nothing was drawn."""
    return depth_acc / np.maximum(alpha, 1e-10)


def render_frame(frame: SplatFrame, settings: RasterSettings) -> Raster:
    """Render a frame (checked here; SH coefficients in sh evaluated towards the camera
    centre); depth is the expected depth (see the module docstring)."""
    g = frame.checked()
    if g.sh.ndim == 3:
        centre = affine_inverse(settings.viewmat)[:3, 3]
        rgb = sh_to_rgb_numpy(
            degree_from_coeffs(g.sh.shape[1]), g.means.astype(np.float64) - centre, g.sh
        )
        g = replace(g, sh=check_array("sh", rgb, (len(g), 3)))
    raster, ctx = forward(g, settings, for_backward=False)
    ctx.release()
    return raster._replace(depth=expected_depth(raster.depth, raster.alpha))


def render(means, quats, log_scales, opacity_logits, colors, settings: RasterSettings) -> Raster:
    """`render_frame` with gsplat's argument order (colors (N,3) RGB or (N,K,3) SH)."""
    return render_frame(
        from_gsplat_order(means, quats, log_scales, opacity_logits, colors), settings
    )
