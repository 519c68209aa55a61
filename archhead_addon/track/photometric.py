"""Photometric refinement of a landmark fit: one texture for the whole clip (CPU).

Landmarks pin about 470 points per frame and leave the surface between them free to slide;
Face Mesh's points also sit a median 2 px from where the embedding puts them, differently
in each expression. The image term ties the whole face region to one texture: points on the
tracked mesh (its vertices and triangle centres) are projected into every kept frame, and
the colour sampled there (bilinear, so the gradient reaches the codes through the image's
own gradient) is compared with an albedo per point shared by the whole clip, times a gain
per frame and a first-order shading fixed to the camera (Charbonnier, weighted by how
squarely the point faces the camera and by the selfie mask). The landmark energy of
`fit.ClipFit` stays in the sum, so the image term refines the fit rather than replacing it.

Sampling points instead of rendering the mesh costs a hundredth and lets every frame take
part in every step; what it leaves out is occlusion, which in the face region is the nose
over a turned cheek, and the view weight already fades such points.

Two stages over the kept frames: the colours alone (the fit fixed), then colours and codes
together, every frame in every step: frames drawn at random per step were cheaper but
left the codes of neighbouring frames refined unevenly (on the real clip the fitted
landmarks' jitter rose from 1.2 to 1.9 px). The focal length stays as the landmarks left
it. The optional per-vertex static offset (`ClipFit(static_offset=True)`) is fitted in the
second stage, where it has data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..flame.model import FlameModel
from ..flame.subset import vertex_subset
from ..timing import Stopwatch
from .embedding import LandmarkEmbedding, face_region
from .fit import ClipFit, corner_matrix, corner_mix, crop_intrinsics, fixed_camera

EYE_JOINTS = slice(3, 5)  # eye_left, eye_right in flame.model.JOINT_NAMES
FACING = (0.2, 0.5)  # cosine to the view ray: weight 0 below the first, 1 above the second


@dataclass
class PhotometricOptions:
    size: int = 256  # the side of the images compared (the crops resized)
    colour_steps: int = 30
    steps: int = 100
    weight: float = 1.0  # the image term against the landmark term
    delta: float = 0.02  # Charbonnier knee, colour units


@dataclass
class PhotometricReport:
    error_before: float  # median over frames of the mean colour error in the face
    error_after: float
    frames: int
    points: int
    seconds: float

    def as_dict(self) -> dict:
        return {k: round(v, 4) if isinstance(v, float) else v for k, v in vars(self).items()}


class FacePoints:
    """Points on a model's face region (without the eyeballs): its vertices and the
    centres of its triangles."""

    def __init__(self, model: FlameModel, emb: LandmarkEmbedding):
        import torch

        from ..flame.lbs_torch import FlameLayer

        region = face_region(model, emb) & (model.weights[:, EYE_JOINTS].sum(axis=1) < 0.5)
        self.ids = np.flatnonzero(region)
        self.layer = FlameLayer(vertex_subset(model, self.ids))
        local = np.full(model.n_verts, -1)
        local[self.ids] = np.arange(len(self.ids))
        self.faces = torch.from_numpy(local[model.faces[region[model.faces].all(axis=1)]])
        self.centres = corner_matrix(self.faces.numpy(), 1 / 3, len(self.ids))

    def __len__(self) -> int:
        return len(self.ids) + len(self.faces)

    def place(self, verts):
        """Points (B,P,3) and unit normals (B,P,3, no gradient: they only weight the points)
        on posed region vertices (B,n,3): the vertices, then the triangles' centres."""
        import torch

        points = torch.cat([verts, corner_mix(self.centres, verts)], dim=1)
        return points, self.normals(verts)

    def normals(self, verts):
        """Unit normals (B,P,3) of the points, without a gradient: area-weighted vertex
        normals, averaged over a triangle's corners for its centre."""
        import torch

        with torch.no_grad():
            a, b, c = (verts[:, self.faces[:, k]] for k in range(3))
            face_n = torch.linalg.cross(b - a, c - a)
            n = torch.zeros_like(verts)
            for k in range(3):
                n.index_add_(1, self.faces[:, k], face_n)
            normals = torch.cat([n, sum(n[:, self.faces[:, k]] for k in range(3))], dim=1)
            return normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def refine_photometric(
    fit: ClipFit,
    images: np.ndarray,
    masks: np.ndarray,
    crop,
    options: PhotometricOptions | None = None,
    progress=None,
) -> PhotometricReport:
    """Refine `fit` (its frames in order) against `images` (T,s,s,3) uint8 and `masks`
    (T,s,s) float of the square `crop` (x0, y0, side) of the source frames."""
    import torch

    opt = options or PhotometricOptions()
    watch = Stopwatch()
    n_frames, size = len(images), images.shape[1]
    points = FacePoints(fit.model, fit.emb)
    K, w2c = fixed_camera(float(fit.focal().item()), fit.size)
    K = crop_intrinsics(K, crop, size)  # the crops' camera
    rotation = torch.from_numpy(w2c[:3, :3]).float()
    shift = torch.from_numpy(w2c[:3, 3]).float()
    # frames as (T,4,s,s): colour and mask sampled together; filled in place, where a float
    # copy of the frames, their stack and its transposed copy took 3x its size at once
    pixels = torch.empty(n_frames, 4, size, size)
    pixels[:, :3].copy_(torch.from_numpy(images).permute(0, 3, 1, 2)).div_(255.0)
    pixels[:, 3].copy_(torch.from_numpy(masks))

    def observe():
        """Sampled colours (B,P,3), weights (B,P) and normals in camera axes (B,P,3)."""
        verts = fit.pose(points.layer, points.ids)
        at, normals = points.place(verts)
        px = fit.project_points(at, K[0, 0], K[:2, 2])
        grid = (2 * px / size - 1)[:, :, None, :]  # (T,P,1,2), align_corners=False
        seen = torch.nn.functional.grid_sample(pixels, grid, align_corners=False)[..., 0]
        seen = seen.permute(0, 2, 1)  # (T,P,4)
        cam = at.detach() @ rotation.T + shift  # camera coordinates
        normals = normals @ rotation.T
        facing = -(normals * cam).sum(-1) / cam.norm(dim=-1).clamp_min(1e-9)
        lo, hi = FACING
        weight = ((facing - lo) / (hi - lo)).clamp(0, 1) * (seen[..., 3].detach() > 0.5)
        return seen[..., :3], weight, normals

    with torch.no_grad():  # the fit as the landmarks left it, which the colour steps keep
        landmark_fit = observe()
        colour0, weight0, _ = landmark_fit
        albedo0 = (colour0 * weight0[..., None]).sum(0) / weight0.sum(0)[:, None].clamp_min(1e-6)
    colour = {
        "albedo": albedo0.contiguous(),
        "gain": torch.ones(n_frames, 3),
        "light": torch.zeros(3),  # camera-fixed first-order shading
    }
    for value in colour.values():
        value.requires_grad_(True)

    def frame_errors(observed=None):
        seen, weight, normals = observe() if observed is None else observed
        shade = 1.0 + normals @ colour["light"]
        model_colour = colour["albedo"][None] * colour["gain"][:, None] * shade[..., None]
        rho = ((seen - model_colour).square() + opt.delta**2).sqrt() - opt.delta
        return (rho.mean(-1) * weight).sum(-1) / weight.sum(-1).clamp_min(1e-6)

    def term(step):
        return opt.weight * frame_errors().mean()

    def colour_term(step):  # the fit does not move: its points are observed once
        return opt.weight * frame_errors(landmark_fit).mean()

    def median_error(observed=None):
        with torch.no_grad():
            return float(frame_errors(observed).median())

    more = [(v, 0.01) for v in colour.values()]
    total = opt.colour_steps + opt.steps
    fit.optimise((), opt.colour_steps, colour_term, progress, 0, total, more=more)
    before = median_error(landmark_fit)
    codes = ("shape", "expr", "jaw", "eyes", "rotation", "translation", "static_offset")
    fit.optimise(codes, opt.steps, term, progress, opt.colour_steps, total, more=more)
    return PhotometricReport(before, median_error(), n_frames, len(points), watch.seconds)
