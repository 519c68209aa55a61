"""Synthetic Gaussian scenes for the tests and the splat benchmark (numpy only)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..rotations import matrix_to_quaternion
from .frame import SplatFrame
from .kernel import RasterSettings


class Scene(NamedTuple):
    """Gaussians (float32, RGB colours in sh) and the camera that sees them."""

    gaussians: SplatFrame
    viewmat: np.ndarray  # (4,4) world-to-camera (OpenCV)
    K: np.ndarray  # (3,3)
    width: int
    height: int

    def settings(self, **options) -> RasterSettings:
        """The kernel's settings for this camera (options: RasterSettings' others)."""
        return RasterSettings(self.viewmat, self.K, self.width, self.height, **options)


def _float32(a) -> np.ndarray:
    return np.asarray(a, np.float32)


def look_at(eye, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-to-camera (OpenCV axes) for a camera at eye looking at target, world y up."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # image right
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image down
    R = np.stack([x, y, z])
    view = np.eye(4)
    view[:3, :3] = R
    view[:3, 3] = -R @ eye
    return view


def intrinsics(width: int, height: int, focal: float, cx=None, cy=None) -> np.ndarray:
    cx = width / 2 if cx is None else cx
    cy = height / 2 if cy is None else cy
    return np.array([[focal, 0, cx], [0, focal, cy], [0, 0, 1]], np.float64)


def face_scene(n: int, width: int = 256, height: int = 256, seed: int = 0,
               distance: float = 0.6) -> Scene:  # fmt: skip
    """Gaussians over a head-sized ellipsoid (semi-axes 8 x 11 x 9.5 cm) seen from `distance`
    metres: flat splats tangent to the surface, about one texel (sqrt(area / n)) across, as a
    UV-parameterised avatar produces. The head fills about 70% of the image height."""
    rng = np.random.default_rng(seed)
    axes = np.array([0.08, 0.11, 0.095])
    # Fibonacci directions with jitter (no two Gaussians at exactly the same depth).
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5**0.5) * i + rng.normal(0, 0.3, n)
    d = np.stack([np.sin(phi) * np.cos(theta), np.cos(phi), np.sin(phi) * np.sin(theta)], -1)
    means = d * axes
    normal = means / axes**2
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    tangent = np.cross(normal, rng.normal(size=(n, 3)))
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    R = np.stack([tangent, np.cross(normal, tangent), normal], -1)  # columns: local axes
    area = 4 * np.pi * (np.prod(axes) ** 1.6 * np.sum(1 / axes**1.6) / 3) ** (1 / 1.6)
    texel = np.sqrt(area / n)
    log_scales = np.log(texel * 0.6) + rng.normal(0, 0.25, (n, 3))
    log_scales[:, 2] += np.log(0.2)  # thin along the normal
    logits = rng.normal(2.0, 1.5, n)
    skin = np.array([0.8, 0.6, 0.5])
    colors = np.clip(skin + rng.normal(0, 0.1, (n, 3)), 0, 1)
    focal = 0.7 * height * distance / (2 * axes[1])
    return Scene(
        SplatFrame(
            means=means, log_scales=log_scales, quats=matrix_to_quaternion(R),
            opacity_logits=logits, sh=colors,
        ).map(_float32),
        look_at((0.0, 0.0, distance), (0.0, 0.0, 0.0)), intrinsics(width, height, focal),
        width, height,
    )  # fmt: skip


def random_scene(n: int, width: int = 32, height: int = 24, seed: int = 0) -> Scene:
    """Random Gaussians in a box in front of the camera (sizes a few pixels to a third of
    the image), random orientations, opacities and colours."""
    rng = np.random.default_rng(seed)
    focal = 1.2 * width
    z = rng.uniform(1.0, 3.0, n)
    x = (rng.uniform(-0.2, 1.2, n) * width - width / 2) * z / focal
    y = (rng.uniform(-0.2, 1.2, n) * height - height / 2) * z / focal
    means = np.stack([x, y, z], -1)
    quats = rng.normal(size=(n, 4))
    log_scales = np.log(z[:, None] / focal * rng.uniform(0.5, 6.0, (n, 3)))
    logits = rng.normal(0.0, 2.0, n)
    colors = rng.uniform(0, 1, (n, 3))
    return Scene(
        SplatFrame(
            means=means, log_scales=log_scales, quats=quats, opacity_logits=logits, sh=colors
        ).map(_float32),
        np.eye(4),
        intrinsics(width, height, focal), width, height,
    )  # fmt: skip
