"""The stability sweep: extreme codes, cameras from 5 cm to 50 m, levels of detail outside
[0, 1] and the fp16 path, each rendered and checked for non-finite values."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from archhead_addon.avatar.runtime import AvatarRuntime
from archhead_addon.evaluate.render import DRIVING_CODES, render_frame

from .sweep import image_change

# log scales are clamped and quaternions normalised by construction; these can run away
ATTRIBUTES = ("means", "opacity_logits", "sh")
EXPRESSIONS = (3.0, -3.0, 6.0, -6.0, 10.0, -10.0)
CAMERA_DISTANCES = (0.05, 0.1, 0.3, 1.0, 3.0, 10.0, 50.0)  # metres from the head's centre
LODS_OUTSIDE = (-1.0, -0.1, 1.1, 2.0)


@dataclass
class StabilityRow:
    case: str
    max_abs: dict[str, float]  # attribute -> its largest |value|
    non_finite: int  # NaN / Inf values in the attributes and the image
    image_change: float  # mean |image - base image|, 8-bit levels


def _cases(n_expr: int, w2c: np.ndarray, centre: np.ndarray):
    """(name, lod, precision, code changes, w2c)."""
    pi = np.pi
    for k in EXPRESSIONS:
        yield f"expressions all {k:+g}", 0.0, "fp32", {"expr": np.full(n_expr, k)}, w2c
    for name, dim in (("jaw", 3), ("neck", 3), ("eyes", 6), ("rotation", 3)):
        for axis in range(3):
            turn = np.zeros(dim)
            turn[axis::3] = pi
            yield f"{name} {'xyz'[axis]} to π", 0.0, "fp32", {name: turn}, w2c
    for d in CAMERA_DISTANCES:
        yield f"camera at {d:g} m", 0.0, "fp32", {}, _camera_at(w2c, centre, d)
    for lod in LODS_OUTSIDE:
        yield f"LOD {lod:g} (clamped)", lod, "fp32", {}, w2c
    yield "fp16", 0.0, "fp16", {}, w2c
    yield "fp16 at LOD 1", 1.0, "fp16", {}, w2c
    yield "fp16, expressions all +10", 0.0, "fp16", {"expr": np.full(n_expr, 10.0)}, w2c
    yield (
        "fp16, jaw, neck and eyes at π",
        0.0,
        "fp16",
        {"jaw": [pi, 0, 0], "neck": [0, pi, 0], "eyes": np.full(6, pi)},
        w2c,
    )


def _camera_at(w2c: np.ndarray, centre: np.ndarray, distance: float) -> np.ndarray:
    """The camera moved along the line from `centre` through it, `distance` metres away."""
    R = w2c[:3, :3]
    eye = -R.T @ w2c[:3, 3]
    direction = (eye - centre) / np.linalg.norm(eye - centre)
    out = np.array(w2c, np.float64)
    out[:3, 3] = -R @ (centre + distance * direction)
    return out


def stability_sweep(
    runtime: AvatarRuntime, item: dict, size: tuple[int, int], background
) -> list[StabilityRow]:
    """Rows for every case, changed from the test frame `item` (its codes and camera)."""
    codes = {k: np.asarray(item["codes"][k], np.float64) for k in DRIVING_CODES}
    K, w2c = item["K"], np.asarray(item["w2c"], np.float64)
    base = render_frame(runtime, 0.0, codes, K, w2c, size, background).rgb
    centre = runtime.decode(0.0, **codes).means.mean(axis=0)
    rows = []
    for name, lod, precision, changes, camera in _cases(len(codes["expr"]), w2c, centre):
        frame_codes = {**codes, **changes}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # LODs outside [0, 1] warn that they are clamped
            g = runtime.decode(lod, precision=precision, **frame_codes)
            rgb = render_frame(
                runtime, lod, frame_codes, K, camera, size, background, precision
            ).rgb
        names = ("means", "log_scales", "quats", "opacity_logits", "sh")
        values = [np.asarray(getattr(g, a), np.float64) for a in names] + [rgb]
        largest = {
            a: float(np.abs(v[np.isfinite(v)]).max(initial=0.0))
            for a, v in zip(names, values, strict=False)
            if a in ATTRIBUTES
        }
        rows.append(
            StabilityRow(
                name,
                largest,
                sum(int((~np.isfinite(v)).sum()) for v in values),
                image_change(rgb, base),
            )
        )
    return rows
