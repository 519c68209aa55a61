"""ctypes binding of the C++ splat kernel. numpy only: Blender's Python uses it directly.

Argument conventions (the same everywhere in `archhead_addon.splat`):
  means (N,3) world positions; quats (N,4) w,x,y,z (normalised inside, zero -> identity);
  log_scales (N,3) natural log of the axis scales (clamped to [-23, 11.5] before exp);
  opacity_logits (N,) (opacity = sigmoid); colors (N,3) RGB after SH evaluation.
  viewmat (4,4) world-to-camera, OpenCV axes (x right, y down, z forward); K (3,3) in
  pixels, pixel (i, j) centred at (i + 0.5, j + 0.5).
Every input must be finite; a non-finite entry raises ValueError naming the array.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from . import build

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
    ]


_ABI_VERSION = 1
_lib: ctypes.CDLL | None = None


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
    _lib = lib
    return lib


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
    num_threads: int = 0  # 0: OpenMP default

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
        p.num_threads = int(self.num_threads)
        return p


def check_array(name: str, x, shape: tuple, dtype=np.float32) -> np.ndarray:
    """C-contiguous float32 (or dtype) copy/view of x with the given shape (-1: any); finite."""
    a = np.ascontiguousarray(x, dtype=dtype)
    if a.ndim != len(shape) or any(s not in (-1, d) for s, d in zip(shape, a.shape, strict=True)):
        want = "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {tuple(a.shape)}")
    bad = a.size - int(np.count_nonzero(np.isfinite(a)))
    if bad:
        raise ValueError(f"{name} contains {bad} non-finite value(s) (NaN, Inf, or beyond float32)")
    return a


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(_F32)


class Gaussians(NamedTuple):
    """Validated kernel inputs (float32, C-contiguous)."""

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    colors: np.ndarray

    @classmethod
    def checked(cls, means, quats, log_scales, opacity_logits, colors) -> Gaussians:
        means = check_array("means", means, (-1, 3))
        n = means.shape[0]
        return cls(
            means,
            check_array("quats", quats, (n, 4)),
            check_array("log_scales", log_scales, (n, 3)),
            check_array("opacity_logits", opacity_logits, (n,)),
            check_array("colors", colors, (n, 3)),
        )


class Projected(NamedTuple):
    means2d: np.ndarray  # (N,2) float64
    conics: np.ndarray  # (N,3)
    depths: np.ndarray  # (N,)
    opacities: np.ndarray  # (N,) sigmoid(logit) (times the AA compensation)
    radii: np.ndarray  # (N,2) int32, 0 when culled


def _raise(err: ctypes.Array) -> None:
    raise ValueError(err.value.decode(errors="replace"))


def project(gaussians: Gaussians, settings: RasterSettings) -> Projected:
    """Per-Gaussian projection exactly as the rasteriser uses it."""
    lib, g, n = library(), gaussians, gaussians.means.shape[0]
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

    def stats(self) -> dict[str, int]:
        out = (ctypes.c_int64 * 2)()
        library().ah_splat_stats(self.handle, out)
        return {"visible": int(out[0]), "intersections": int(out[1])}

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


def forward(gaussians: Gaussians, settings: RasterSettings) -> tuple[Raster, ForwardContext]:
    lib, g, n = library(), gaussians, gaussians.means.shape[0]
    h, w = int(settings.height), int(settings.width)
    out = Raster(
        np.empty((h, w, 3), np.float32), np.empty((h, w), np.float32),
        np.empty((h, w), np.float32),
    )  # fmt: skip
    err = ctypes.create_string_buffer(_ERR_LEN)
    params = settings.to_c()
    handle = lib.ah_splat_forward(
        ctypes.byref(params), n, _ptr(g.means), _ptr(g.log_scales), _ptr(g.quats),
        _ptr(g.opacity_logits), _ptr(g.colors), _ptr(out.rgb), _ptr(out.alpha),
        _ptr(out.depth), err, _ERR_LEN,
    )  # fmt: skip
    if not handle:
        _raise(err)
    return out, ForwardContext(handle, n, (h, w))


class Grads(NamedTuple):
    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    colors: np.ndarray


def backward(ctx: ForwardContext, g_rgb, g_alpha=None, g_depth=None) -> Grads:
    """Gradients of the inputs given dL/d(rgb, alpha, accumulated depth)."""
    h, w = ctx.shape
    g_rgb = check_array("g_rgb", g_rgb, (h, w, 3))
    g_alpha = None if g_alpha is None else check_array("g_alpha", g_alpha, (h, w))
    g_depth = None if g_depth is None else check_array("g_depth", g_depth, (h, w))
    n = ctx.n
    out = Grads(
        np.empty((n, 3), np.float32), np.empty((n, 4), np.float32),
        np.empty((n, 3), np.float32), np.empty(n, np.float32), np.empty((n, 3), np.float32),
    )  # fmt: skip
    err = ctypes.create_string_buffer(_ERR_LEN)
    rc = library().ah_splat_backward(
        ctx.handle, _ptr(g_rgb), None if g_alpha is None else _ptr(g_alpha),
        None if g_depth is None else _ptr(g_depth), _ptr(out.means), _ptr(out.log_scales),
        _ptr(out.quats), _ptr(out.opacity_logits), _ptr(out.colors), err, _ERR_LEN,
    )  # fmt: skip
    if rc != 0:
        _raise(err)
    return out


def expected_depth(depth_acc: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Accumulated depth divided by alpha (gsplat's "ED"); 0 where nothing was drawn."""
    return depth_acc / np.maximum(alpha, 1e-10)


def render(means, quats, log_scales, opacity_logits, colors, settings: RasterSettings) -> Raster:
    """Render with numpy arrays; depth is the expected depth (see module docstring)."""
    raster, ctx = forward(
        Gaussians.checked(means, quats, log_scales, opacity_logits, colors), settings
    )
    ctx.release()
    return raster._replace(depth=expected_depth(raster.depth, raster.alpha))
