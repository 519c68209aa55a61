"""Where MediaPipe's 478 landmarks sit on a FLAME-format model, derived from the model itself.

The neutral model is rendered from a few head turns (its albedo where it has one, shaded grey
otherwise); Face Mesh runs on every render, and each landmark is cast back onto the mesh
through the pixel it lands on (the exact point inside the triangle, perspective-correct).
A landmark's views are combined by taking the view closest to their median 3D point; how far
the views spread says how well the landmark is defined on this model (contour points that
slide with the silhouette spread most) and becomes its weight in fitting.

The result is cached beside the UV layouts (`$ARCHHEAD_CACHE`), named by a hash of the mesh.
No landmark embedding of FLAME's authors is used.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..flame.lbs import forward
from ..flame.model import FlameModel
from ..io.atomic import save_npz_atomic
from ..paths import cache_dir
from ..rotations import axis_angle_to_matrix
from .detect import N_LANDMARKS, FaceDetector
from .render import render_mesh

EMBEDDING_VERSION = 1
VIEW_YAWS = (-0.45, -0.25, 0.0, 0.25, 0.45)  # radians of head turn in the renders
RENDER_SIZE = 512
SPREAD_SCALE = 0.004  # metres; weight = 1 / (1 + (spread / SPREAD_SCALE)^2)
MIN_VIEWS = 2
FACE_RADIUS = 0.01  # metres: the face region is the mesh within this of a landmark


@dataclass(frozen=True)
class LandmarkEmbedding:
    faces: np.ndarray  # (478,) int64 triangle of each landmark
    bary: np.ndarray  # (478,3) barycentric coordinates in it
    weight: np.ndarray  # (478,) in [0, 1]; 0 for landmarks not found on the model
    spread: np.ndarray  # (478,) metres between views (median distance to the chosen point)

    def points(self, verts: np.ndarray, model_faces: np.ndarray) -> np.ndarray:
        """Landmark positions (...,478,3) on posed vertices (...,V,3)."""
        return np.einsum("...lkc,lk->...lc", verts[..., model_faces[self.faces], :], self.bary)


def _mesh_hash(model: FlameModel) -> str:
    h = hashlib.sha256()
    for a in (model.v_template.astype(np.float64), model.faces.astype(np.int64)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(f"v{EMBEDDING_VERSION}".encode())
    return h.hexdigest()[:20]


def landmark_embedding(model: FlameModel, cache=None) -> LandmarkEmbedding:
    """The model's embedding, from the cache or derived (a few seconds) and cached."""
    path = Path(cache or cache_dir()) / f"landmarks-{_mesh_hash(model)}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                emb = LandmarkEmbedding(z["faces"], z["bary"], z["weight"], z["spread"])
            if emb.faces.shape == (N_LANDMARKS,) and np.isfinite(emb.bary).all():
                return emb
        except (OSError, ValueError, KeyError) as exc:
            warnings.warn(
                f"{path}: unreadable landmark cache ({exc}); deriving it again", stacklevel=2
            )
    emb = derive_embedding(model)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_npz_atomic(path, faces=emb.faces, bary=emb.bary, weight=emb.weight, spread=emb.spread)
    return emb


def view_camera(yaw: float, size: int = RENDER_SIZE):
    """K and an OpenCV w2c looking at the face from the front, turned by `yaw`."""
    f = 1.8 * size
    K = np.array([[f, 0.0, size / 2], [0.0, f, size / 2], [0.0, 0.0, 1.0]])
    w2c = np.diag([1.0, -1.0, -1.0, 1.0])
    w2c[:3, :3] = w2c[:3, :3] @ axis_angle_to_matrix(np.array([0.0, yaw, 0.0]))
    w2c[:3, 3] = [0.0, 0.02, 0.6]
    return K, w2c


def _cast(point2d, face, verts, faces, K, w2c) -> np.ndarray:
    """Perspective-correct barycentrics of the pixel position `point2d` in triangle `face`."""
    cam = verts[faces[face]] @ w2c[:3, :3].T + w2c[:3, 3]
    xy = (cam @ K.T)[:, :2] / cam[:, 2:3]
    a, b, c = xy
    m = np.array([b - a, c - a]).T
    try:
        s, t = np.linalg.solve(m, point2d - a)
    except np.linalg.LinAlgError:
        return None
    screen = np.clip(np.array([1 - s - t, s, t]), 0, 1)
    persp = screen / cam[:, 2]
    return persp / persp.sum()


def derive_embedding(model: FlameModel) -> LandmarkEmbedding:
    verts = forward(model)[0]
    faces = model.faces
    found = np.zeros((len(VIEW_YAWS), N_LANDMARKS), bool)
    tri = np.zeros((len(VIEW_YAWS), N_LANDMARKS), np.int64)
    bary = np.zeros((len(VIEW_YAWS), N_LANDMARKS, 3))
    with FaceDetector(video=False, max_faces=1, masks=False, hands=False) as detect:
        for v, yaw in enumerate(VIEW_YAWS):
            K, w2c = view_camera(yaw)
            rgb, _, face_at, _ = render_mesh(model, verts, K, w2c, (RENDER_SIZE,) * 2)
            background = 0.5 * (face_at < 0)[..., None]
            image = np.round(np.clip(rgb + background, 0, 1) * 255).astype(np.uint8)
            lm = detect(image).landmarks
            if lm is None:
                continue
            px = np.clip(lm.astype(np.int64), 0, RENDER_SIZE - 1)
            for i in range(N_LANDMARKS):
                face = face_at[px[i, 1], px[i, 0]]
                if face < 0:
                    continue
                b = _cast(lm[i], face, verts, faces, K, w2c)
                if b is not None:
                    found[v, i], tri[v, i], bary[v, i] = True, face, b
    if found.any(axis=1).sum() < MIN_VIEWS:
        raise RuntimeError(
            f"{model.source}: Face Mesh found the model's face in fewer than "
            f"{MIN_VIEWS} of {len(VIEW_YAWS)} renders; cannot place landmarks"
        )
    points = np.einsum("vlkc,vlk->vlc", verts[faces[tri]], bary)  # (views,478,3)
    out_faces = np.zeros(N_LANDMARKS, np.int64)
    out_bary = np.full((N_LANDMARKS, 3), 1 / 3)
    weight = np.zeros(N_LANDMARKS)
    spread = np.full(N_LANDMARKS, np.inf)
    for i in range(N_LANDMARKS):
        views = np.flatnonzero(found[:, i])
        if len(views) < MIN_VIEWS:
            continue
        p = points[views, i]
        dist = np.linalg.norm(p - np.median(p, axis=0), axis=1)
        best = views[np.argmin(dist)]
        out_faces[i], out_bary[i] = tri[best, i], bary[best, i]
        spread[i] = np.median(np.linalg.norm(p - points[best, i], axis=1))
        weight[i] = 1.0 / (1.0 + (spread[i] / SPREAD_SCALE) ** 2)
    return LandmarkEmbedding(out_faces, out_bary, weight, spread)


def face_region(model: FlameModel, emb: LandmarkEmbedding | None = None) -> np.ndarray:
    """(V,) bool: the vertices within FACE_RADIUS of a well-placed landmark on the neutral."""
    emb = emb or landmark_embedding(model)
    points = emb.points(model.v_template, model.faces)[emb.weight > 0.5]
    dist = np.linalg.norm(model.v_template[:, None] - points[None], axis=-1).min(axis=1)
    return dist < FACE_RADIUS
