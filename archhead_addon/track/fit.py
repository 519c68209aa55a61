"""Fitting FLAME to 2D landmarks over a whole clip at once (torch, CPU).

Unknowns: one identity (the leading `n_shape` components, and optionally a per-vertex static
offset), per frame the expression, jaw, eyes, global rotation and translation, and one focal
length (fitted unless given). The camera is fixed (OpenCV, on FLAME's +z axis looking down
-z, principal point at the image centre); the head moves in front of it. Only the vertices
under the landmarks are posed (`flame.subset`), so every frame of a clip is optimised in one
batch.

Energy, per frame (landmark residuals r in units of the clip's face size):
  data      sum_l w_l rho(|r_l|) / sum_l w_l, rho the Charbonnier (quadratic under ~2 px)
  priors    shape and expression coefficients, eye and jaw rotations (squared)
  temporal  squared differences of neighbouring frames' codes (per second of gap)
  offset    (when fitted) its size and its differences along mesh edges (squared)
Two stages: the rigid pose and focal length first, then everything. `track.photometric`
adds an image term to the same energy and goes on from there.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..flame.model import FlameModel
from ..flame.subset import vertex_subset
from ..sequences import Sequence
from ..timing import Stopwatch
from .embedding import LandmarkEmbedding

CAMERA_DISTANCE = 1.0  # metres from the FLAME origin to the camera at the rest pose
# Outer cheek points of Face Mesh (left / right of the image); their span sets the scale.
SPAN_LANDMARKS = (234, 454)
PER_FRAME = ("expr", "jaw", "eyes", "rotation", "translation")
ONCE = ("shape", "static_offset")
LEARNING_RATES = {
    "shape": 0.05,
    "expr": 0.05,
    "jaw": 0.01,
    "eyes": 0.02,
    "rotation": 0.01,
    "translation": 0.002,
    "log_focal": 0.01,
    "static_offset": 2e-4,  # metres
}


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
            "offset": 30.0,  # per square metre of mean offset
            "offset_edges": 3e3,  # per square metre of mean difference along an edge
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

    def select(self, rows) -> FitResult:
        """The result for frames `rows` only (the shape and camera unchanged)."""
        per_frame = {k: v if k in ONCE else v[rows] for k, v in self.codes.items()}
        return replace(
            self,
            codes=per_frame,
            residual_px=self.residual_px[rows],
            landmark_residual_px=self.landmark_residual_px[rows],
            projected=self.projected[rows],
        )


def fixed_camera(focal: float, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    height, width = size
    K = np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])
    w2c = np.diag([1.0, -1.0, -1.0, 1.0])
    w2c[2, 3] = CAMERA_DISTANCE
    return K, w2c


def crop_intrinsics(K: np.ndarray, crop, size: int) -> np.ndarray:
    """Intrinsics `K` of the source frames seen through their square crop (x0, y0, side)
    resized to `size` pixels."""
    x0, y0, side = crop
    scale = size / side
    K = K.copy()
    K[:2] *= scale
    K[0, 2] -= x0 * scale
    K[1, 2] -= y0 * scale
    return K


class ClipFit:
    """A clip's unknowns (`p`, torch leaves) and the landmark energy over them.

    `init`: codes to start from (FitResult.codes of these frames); without it the pose
    starts from the landmarks' position and span. The focal length starts from
    `options.focal` (then held) or its prior.
    """

    def __init__(
        self,
        model: FlameModel,
        emb: LandmarkEmbedding,
        landmarks: np.ndarray,
        frame_ids: np.ndarray,
        fps: float,
        size: tuple[int, int],
        options: FitOptions | None = None,
        init: dict | None = None,
        static_offset: bool = False,
    ):
        import torch

        from ..flame.lbs_torch import FlameLayer

        self.opt = opt = options or FitOptions()
        self.model, self.emb, self.size = model, emb, size
        n_frames = len(landmarks)
        self.n_shape, self.n_expr = min(opt.n_shape, model.n_shape), min(opt.n_expr, model.n_expr)
        used, inverse = np.unique(model.faces[emb.faces], return_inverse=True)
        self.landmark_vertices = used
        self.layer = FlameLayer(vertex_subset(model, used))
        self.landmark_matrix = corner_matrix(inverse.reshape(-1, 3), emb.bary, len(used))
        self.target = torch.from_numpy(landmarks.astype(np.float32))
        self.weight = torch.from_numpy(emb.weight.astype(np.float32))
        self.j_regressor = torch.from_numpy(model.j_regressor.astype(np.float32))
        self.edges = torch.from_numpy(_edges(model.faces))
        spans = np.linalg.norm(
            landmarks[:, SPAN_LANDMARKS[0]] - landmarks[:, SPAN_LANDMARKS[1]], axis=-1
        )
        self.scale = float(max(np.median(spans), 1.0))  # pixels per face size
        height, width = size
        self.log_focal0 = float(np.log(opt.focal or 1.2 * max(height, width)))
        if init is None:
            init = _initial_pose(model, emb, landmarks, size, float(np.exp(self.log_focal0)))
        self.p = self._parameters(n_frames, init, static_offset)
        gaps = np.maximum(np.diff(frame_ids), 1).astype(np.float32) / max(fps, 1e-6) * 25.0
        self.gap_w = torch.from_numpy(1.0 / gaps)[:, None]  # neighbours further apart bind less

    def _parameters(self, n_frames: int, init: dict, static_offset: bool) -> dict:
        import torch

        def start(key, width):
            value = init.get(key)
            if value is None:
                return torch.zeros(n_frames, width)
            return torch.tensor(np.asarray(value)[:, :width], dtype=torch.float32)

        shape = np.zeros(self.n_shape)
        if init.get("shape") is not None:
            shape = np.asarray(init["shape"])[: self.n_shape]
        p = {
            "shape": torch.tensor(shape[None], dtype=torch.float32),
            "expr": start("expr", self.n_expr),
            "jaw": start("jaw", 3),
            "eyes": start("eyes", 6),
            "rotation": start("rotation", 3),
            "translation": start("translation", 3),
            "log_focal": torch.tensor([self.log_focal0], dtype=torch.float32),
        }
        if static_offset:
            p["static_offset"] = torch.zeros(self.model.n_verts, 3)
        for v in p.values():
            v.requires_grad_(True)
        return p

    def subset_offset(self, vertex_ids):
        """The static offset of vertices `vertex_ids` and of the five joint carriers that
        `vertex_subset` appends (the joints move with the whole mesh's offset)."""
        import torch

        offset = self.p.get("static_offset")
        if offset is None:
            return None
        return torch.cat([offset[torch.as_tensor(vertex_ids)], self.j_regressor @ offset])

    def pose(self, layer, vertex_ids):
        """Posed vertices (T,n,3) of a `vertex_subset` layer over `vertex_ids`."""
        p = self.p
        return layer(
            shape=p["shape"],
            expr=p["expr"],
            jaw=p["jaw"],
            eyes=p["eyes"],
            rotation=p["rotation"],
            translation=p["translation"],
            static_offset=self.subset_offset(vertex_ids),
        )[:, : len(vertex_ids)]

    def focal(self):
        import torch

        return torch.exp(self.p["log_focal"])

    @staticmethod
    def project_points(pts, focal, centre):
        """Pixels (...,2) of FLAME-space points (...,3) seen by the fixed camera with focal
        length `focal` and principal point `centre` (x, y) in pixels."""
        import torch

        cam_x, cam_y = pts[..., 0], -pts[..., 1]
        cam_z = (CAMERA_DISTANCE - pts[..., 2]).clamp_min(1e-3)
        return torch.stack(
            [focal * cam_x / cam_z + centre[0], focal * cam_y / cam_z + centre[1]], -1
        )

    def project(self):
        verts = self.pose(self.layer, self.landmark_vertices)  # (T,n,3)
        pts = corner_mix(self.landmark_matrix, verts)  # (T,478,3)
        height, width = self.size
        return self.project_points(pts, self.focal(), (width / 2, height / 2))

    def _smooth(self, key):
        d = self.p[key][1:] - self.p[key][:-1]
        return (self.gap_w * d.square()).sum(-1).mean() if len(d) else d.sum() * 0

    def energy(self):
        """(energy, landmark data term)."""
        p, w, opt = self.p, self.opt.weights, self.opt
        r = (self.project() - self.target).norm(dim=-1) / self.scale
        rho = (r.square() + opt.delta**2).sqrt() - opt.delta
        data = ((rho * self.weight).sum(-1) / self.weight.sum()).mean()
        n_frames = len(p["expr"])
        e = data + w["shape"] * p["shape"].square().sum() / max(n_frames, 1) ** 0.5
        e = e + w["expr"] * p["expr"].square().sum(-1).mean()
        e = e + w["jaw"] * p["jaw"].square().sum(-1).mean()
        e = e + w["eyes"] * p["eyes"].square().sum(-1).mean()
        e = e + w["focal"] * (p["log_focal"] - self.log_focal0).square().sum()
        e = (
            e
            + w["smooth_expr"] * self._smooth("expr")
            + w["smooth_pose"] * (self._smooth("rotation") + self._smooth("jaw"))
            + w["smooth_translation"] * self._smooth("translation")
            + w["smooth_eyes"] * self._smooth("eyes")
        )
        offset = p.get("static_offset")
        if offset is not None:
            along = offset[self.edges[:, 0]] - offset[self.edges[:, 1]]
            e = e + w["offset"] * offset.square().sum(-1).mean()
            e = e + w["offset_edges"] * along.square().sum(-1).mean()
        return e, data

    def optimise(
        self, keys, steps: int, extra=None, progress=None, done: int = 0, total=None, more=()
    ):
        """Adam with a cosine schedule over `keys` and the (tensor, learning rate) pairs
        `more`; `extra(step)` adds terms to the energy. With no keys the fit stays put and
        its own energy is a constant, taken once."""
        import torch

        keys = [k for k in keys if k in self.p and (k != "log_focal" or self.opt.focal is None)]
        groups = [{"params": [self.p[k]], "lr": LEARNING_RATES[k]} for k in keys]
        adam = torch.optim.Adam(groups + [{"params": [t], "lr": lr} for t, lr in more])
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(adam, steps, eta_min=0.0)
        fixed = None
        if not keys:
            with torch.no_grad():
                fixed = self.energy()
        for step in range(steps):
            adam.zero_grad()
            e, data = self.energy() if fixed is None else fixed
            if extra is not None:
                e = e + extra(step)
            e.backward()
            adam.step()
            sched.step()
            if progress is not None and (done + step + 1) % 20 == 0:
                progress(done + step + 1, total or steps, data.item())

    def codes(self) -> dict:
        """The fitted codes at the model's full widths (zeros beyond the fitted components),
        so that readers of the tracking do not warn about padding."""
        p, model = self.p, self.model
        codes = {k: p[k].detach().numpy().astype(np.float64) for k in PER_FRAME}
        codes["shape"] = np.zeros(model.n_shape)
        codes["shape"][: self.n_shape] = p["shape"].detach().numpy()[0]
        codes["expr"] = np.pad(codes["expr"], ((0, 0), (0, model.n_expr - self.n_expr)))
        codes["neck"] = np.zeros((len(codes["expr"]), 3))
        if "static_offset" in p:
            codes["static_offset"] = p["static_offset"].detach().numpy().astype(np.float64)
        return codes

    def result(self, seconds: float) -> FitResult:
        import torch

        with torch.no_grad():
            projected = self.project()
            residual = (projected - self.target).norm(dim=-1).numpy().astype(np.float64)
        focal = float(self.focal().item())
        K, w2c = fixed_camera(focal, self.size)
        good = self.emb.weight > 0.5
        return FitResult(
            self.codes(),
            focal,
            K,
            w2c,
            np.median(residual[:, good], axis=1),
            residual,
            projected.numpy().astype(np.float64),
            seconds,
        )


def corner_matrix(corners: np.ndarray, weights, n_verts: int):
    """Points that mix three corner vertices each ((P,3) indices, (P,3) or scalar weights)
    as a sparse (P, n_verts) matrix: `corner_mix` with it is about 3x faster than gathering
    the corners, forward and backward."""
    import torch

    n_points = len(corners)
    weights = np.broadcast_to(np.asarray(weights, np.float32), corners.shape)
    return torch.sparse_coo_tensor(
        np.stack([np.repeat(np.arange(n_points), 3), corners.reshape(-1)]),
        weights.reshape(-1),
        (n_points, n_verts),
        check_invariants=True,
    ).coalesce()


def corner_mix(matrix, verts):
    """The points (B,P,3) of a `corner_matrix` on vertices (B,n,3)."""
    import torch

    n_frames, n_verts = verts.shape[:2]
    mixed = torch.sparse.mm(matrix, verts.transpose(0, 1).reshape(n_verts, -1))
    return mixed.view(-1, n_frames, 3).transpose(0, 1)


def _edges(faces: np.ndarray) -> np.ndarray:
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0)


def _initial_pose(model, emb, landmarks, size, focal: float) -> dict:
    """Translation from the face's span (depth) and the landmarks' centre (x, y)."""
    height, width = size
    neutral = emb.points(model.v_template, model.faces)
    span_m = float(np.linalg.norm(neutral[SPAN_LANDMARKS[0]] - neutral[SPAN_LANDMARKS[1]]))
    spans = np.linalg.norm(
        landmarks[:, SPAN_LANDMARKS[0]] - landmarks[:, SPAN_LANDMARKS[1]], axis=-1
    )
    depth = focal * span_m / spans
    centre = landmarks.mean(axis=1)
    x = (centre[:, 0] - width / 2) * depth / focal
    y = -(centre[:, 1] - height / 2) * depth / focal
    return {"translation": np.stack([x, y, CAMERA_DISTANCE - depth], 1)}


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

    watch = Stopwatch()
    torch.manual_seed(0)
    fit = ClipFit(model, emb, landmarks, frame_ids, fps, size, options)
    opt = fit.opt
    total = opt.rigid_steps + opt.full_steps
    fit.optimise(
        ("rotation", "translation", "log_focal"), opt.rigid_steps, None, progress, 0, total
    )
    fit.optimise(tuple(LEARNING_RATES), opt.full_steps, None, progress, opt.rigid_steps, total)
    return fit.result(watch.seconds)


def fitted_sequence(codes: dict, frame_ids, fps: float, source: str, **camera) -> Sequence:
    """The fitted codes (shape once, the rest per frame) as a tracked Sequence; `camera`:
    K, w2c, image_size, as Sequence takes them."""
    n = len(codes["expr"])
    per_frame = {k: codes[k] for k in ("expr", "jaw", "neck", "eyes", "rotation", "translation")}
    return Sequence(
        shape=np.tile(codes["shape"], (n, 1)),
        **per_frame,
        static_offset=codes.get("static_offset"),
        fps=fps,
        frame_ids=frame_ids,
        source=source,
        format="archhead-track",
        **camera,
    ).validate()
