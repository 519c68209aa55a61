"""Fitting FLAME to 2D landmarks over a whole clip at once (torch, CPU).

Unknowns: one identity (the leading `n_shape` components), per frame the expression, jaw,
eyes, global rotation and translation, and one focal length (fitted unless given). The
camera is fixed (OpenCV, on FLAME's +z axis looking down -z, principal point at the image
centre); the head moves in front of it. Only the vertices under the landmarks are posed
(`flame.subset`), so every frame of a clip is optimised in one batch.

Energy, per frame (landmark residuals r in units of the clip's face size):
  data      sum_l w_l rho(|r_l|) / sum_l w_l, rho the Charbonnier (quadratic under ~2 px)
  priors    shape and expression coefficients, eye and jaw rotations (squared)
  temporal  squared differences of neighbouring frames' codes (per second of gap)
Two stages: the rigid pose and focal length first, then everything.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..flame.model import FlameModel
from ..flame.subset import vertex_subset
from ..sequences import Sequence
from ..timing import Stopwatch
from .embedding import LandmarkEmbedding

CAMERA_DISTANCE = 1.0  # metres from the FLAME origin to the camera at the rest pose
# Outer cheek points of Face Mesh (left / right of the image); their span sets the scale.
SPAN_LANDMARKS = (234, 454)


@dataclass
class FitOptions:
    n_shape: int = 100
    n_expr: int = 100
    focal: float | None = None  # pixels at the frames' size; None: fitted
    rigid_steps: int = 120
    full_steps: int = 400
    delta: float = 0.008  # Charbonnier knee, in face sizes (about 2 px on a 250 px face)
    weights: dict = field(
        default_factory=lambda: {
            "shape": 3e-5,
            "expr": 3e-5,
            "jaw": 1e-3,
            "eyes": 1e-4,
            "focal": 1e-3,
            "smooth_expr": 3e-4,
            "smooth_pose": 3e-2,
            "smooth_translation": 3.0,
            "smooth_eyes": 3e-4,
        }
    )


@dataclass
class FitResult:
    codes: dict  # shape (S,), and (T,n) expr, jaw, neck, eyes, rotation, translation
    focal: float
    K: np.ndarray  # (3,3) at the frames' size
    w2c: np.ndarray  # (4,4)
    residual_px: np.ndarray  # (T,) median landmark residual per frame, pixels
    landmark_residual_px: np.ndarray  # (T,478)
    projected: np.ndarray  # (T,478,2) the fitted landmarks, pixels
    seconds: float


def fixed_camera(focal: float, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    height, width = size
    K = np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
    w2c = np.diag([1.0, -1.0, -1.0, 1.0])
    w2c[2, 3] = CAMERA_DISTANCE
    return K, w2c


def fit_landmarks(
    model: FlameModel,
    emb: LandmarkEmbedding,
    landmarks: np.ndarray,
    frame_ids: np.ndarray,
    fps: float,
    size: tuple[int, int],
    options: FitOptions | None = None,
    progress=None,
) -> FitResult:
    """Fit `landmarks` (T,478,2) pixels of frames `frame_ids` (size (H, W))."""
    import torch

    from ..flame.lbs_torch import FlameLayer

    opt = options or FitOptions()
    watch = Stopwatch()
    torch.manual_seed(0)
    n_frames = len(landmarks)
    n_shape, n_expr = min(opt.n_shape, model.n_shape), min(opt.n_expr, model.n_expr)
    corner_ids = model.faces[emb.faces]  # (478,3)
    used, inverse = np.unique(corner_ids, return_inverse=True)
    layer = FlameLayer(vertex_subset(model, used))
    corner_index = torch.from_numpy(inverse.reshape(-1, 3))
    bary = torch.from_numpy(emb.bary.astype(np.float32))
    target = torch.from_numpy(landmarks.astype(np.float32))
    weight = torch.from_numpy(emb.weight.astype(np.float32))
    height, width = size

    span_px = np.median(
        np.linalg.norm(landmarks[:, SPAN_LANDMARKS[0]] - landmarks[:, SPAN_LANDMARKS[1]], axis=-1)
    )
    scale = float(max(span_px, 1.0))  # pixels per face size
    neutral = emb.points(model.v_template, model.faces)
    span_m = float(np.linalg.norm(neutral[SPAN_LANDMARKS[0]] - neutral[SPAN_LANDMARKS[1]]))
    focal0 = float(opt.focal or 1.2 * max(height, width))
    log_focal0 = np.log(focal0)

    # Initial translation: depth from the face span, x/y from the landmarks' centre.
    depth = (
        focal0
        * span_m
        / np.linalg.norm(landmarks[:, SPAN_LANDMARKS[0]] - landmarks[:, SPAN_LANDMARKS[1]], axis=-1)
    )
    centre = landmarks.mean(axis=1)
    x = (centre[:, 0] - width / 2) * depth / focal0
    y = -(centre[:, 1] - height / 2) * depth / focal0
    z = CAMERA_DISTANCE - depth
    p = {
        "shape": torch.zeros(1, n_shape),
        "expr": torch.zeros(n_frames, n_expr),
        "jaw": torch.zeros(n_frames, 3),
        "eyes": torch.zeros(n_frames, 6),
        "rotation": torch.zeros(n_frames, 3),
        "translation": torch.from_numpy(np.stack([x, y, z], 1).astype(np.float32)),
        "log_focal": torch.tensor([log_focal0], dtype=torch.float32),
    }
    for v in p.values():
        v.requires_grad_(True)
    gaps = np.maximum(np.diff(frame_ids), 1).astype(np.float32) / max(fps, 1e-6) * 25.0
    gap_w = torch.from_numpy(1.0 / gaps)[:, None]  # neighbours further apart bind less

    def project():
        verts = layer(
            shape=p["shape"],
            expr=p["expr"],
            jaw=p["jaw"],
            eyes=p["eyes"],
            rotation=p["rotation"],
            translation=p["translation"],
        )
        pts = (verts[:, corner_index] * bary[None, :, :, None]).sum(2)  # (T,478,3)
        cam_x, cam_y, cam_z = pts[..., 0], -pts[..., 1], CAMERA_DISTANCE - pts[..., 2]
        f = torch.exp(p["log_focal"])
        cam_z = cam_z.clamp_min(1e-3)
        return torch.stack([f * cam_x / cam_z + width / 2, f * cam_y / cam_z + height / 2], -1)

    w = opt.weights

    def smooth(key):
        d = p[key][1:] - p[key][:-1]
        return (gap_w * d.square()).sum(-1).mean() if n_frames > 1 else d.sum() * 0

    def energy():
        r = (project() - target).norm(dim=-1) / scale
        rho = torch.sqrt(r.square() + opt.delta**2) - opt.delta
        data = ((rho * weight).sum(-1) / weight.sum()).mean()
        e = data + w["shape"] * p["shape"].square().sum() / max(n_frames, 1) ** 0.5
        e = e + w["expr"] * p["expr"].square().sum(-1).mean()
        e = e + w["jaw"] * p["jaw"].square().sum(-1).mean()
        e = e + w["eyes"] * p["eyes"].square().sum(-1).mean()
        e = e + w["focal"] * (p["log_focal"] - log_focal0).square().sum()
        e = (
            e
            + w["smooth_expr"] * smooth("expr")
            + w["smooth_pose"] * (smooth("rotation") + smooth("jaw"))
            + w["smooth_translation"] * smooth("translation")
            + w["smooth_eyes"] * smooth("eyes")
        )
        return e, data

    lrs = {
        "shape": 0.05,
        "expr": 0.05,
        "jaw": 0.01,
        "eyes": 0.02,
        "rotation": 0.01,
        "translation": 0.002,
        "log_focal": 0.01,
    }
    stages = [
        (("rotation", "translation", "log_focal"), opt.rigid_steps),
        (tuple(lrs), opt.full_steps),
    ]
    total = sum(steps for _, steps in stages)
    done = 0
    for keys, steps in stages:
        keys = [k for k in keys if k != "log_focal" or opt.focal is None]
        adam = torch.optim.Adam([{"params": [p[k]], "lr": lrs[k]} for k in keys])
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(adam, steps, eta_min=0.0)
        for _ in range(steps):
            adam.zero_grad()
            e, data = energy()
            e.backward()
            adam.step()
            sched.step()
            done += 1
            if progress is not None and done % 20 == 0:
                progress(done, total, data.item())
    with torch.no_grad():
        projected = project()
        residual = (projected - target).norm(dim=-1).numpy().astype(np.float64)
    focal = float(np.exp(p["log_focal"].item()))
    K, w2c = fixed_camera(focal, size)
    codes = {
        k: p[k].detach().numpy().astype(np.float64)
        for k in ("expr", "jaw", "eyes", "rotation", "translation")
    }
    # the model's full widths (zeros beyond the fitted components), so that readers of the
    # tracking do not warn about padding
    codes["shape"] = np.zeros(model.n_shape)
    codes["shape"][:n_shape] = p["shape"].detach().numpy()[0]
    codes["expr"] = np.pad(codes["expr"], ((0, 0), (0, model.n_expr - n_expr)))
    codes["neck"] = np.zeros((n_frames, 3))
    good = emb.weight > 0.5
    return FitResult(
        codes,
        focal,
        K,
        w2c,
        np.median(residual[:, good], axis=1),
        residual,
        projected.numpy().astype(np.float64),
        watch.seconds,
    )


def fitted_sequence(codes: dict, frame_ids, fps: float, source: str, **camera) -> Sequence:
    """The fitted codes (shape once, the rest per frame) as a tracked Sequence; `camera`:
    K, w2c, image_size, as Sequence takes them."""
    n = len(codes["expr"])
    per_frame = {k: codes[k] for k in ("expr", "jaw", "neck", "eyes", "rotation", "translation")}
    return Sequence(
        shape=np.tile(codes["shape"], (n, 1)),
        **per_frame,
        fps=fps,
        frame_ids=frame_ids,
        source=source,
        format="archhead-track",
        **camera,
    ).validate()
