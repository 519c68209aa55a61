"""Leaving out the Gaussians a camera cannot see, before they are decoded.

Each texel's Gaussian lies near the texel's point on the posed surface: its decoded offset
away (mostly static shape: on a real subject hair lies up to 10 cm off the head) plus about
three standard deviations of its own extent. The runtime measures that reach per texel once
per level, on the neutral frame, and widens it (REACH_FACTOR, REACH_PAD) for what
expressions change; a texel whose surface point lies further than its reach outside the
camera's frustum is neither decoded nor drawn.

Back faces are not culled: it does not pay. The offsets that carry hair move Gaussians of
back-facing surfaces into view: on the real avatar, culling every texel on a surface facing
away dropped the render to 19 dB against the unculled one, and culling only those that stay
within 3 cm of their surface left 38 dB for 7 % fewer Gaussians.
docs/blender_avatar.md ("Culling") has the measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SIGMAS = 3.0  # a Gaussian's drawn extent, in standard deviations (as the kernel's cut-off)
REACH_FACTOR = 1.25  # expressions and jaw move offsets: the neutral reach, widened
REACH_PAD = 0.005  # metres added to every reach


def reach(offsets: np.ndarray, log_scales: np.ndarray) -> np.ndarray:
    """(N,) metres: how far each Gaussian can reach from its surface point, with margin."""
    extent = np.linalg.norm(offsets, axis=1) + SIGMAS * np.exp(log_scales.max(axis=1))
    return (REACH_FACTOR * extent + REACH_PAD).astype(np.float32)


@dataclass(frozen=True)
class ViewFrustum:
    """A pinhole camera's view volume in the avatar's own (FLAME) space.

    viewmat: OpenCV world-to-camera (4x4) of that space; tan_x, tan_y: the image's extent at
    depth 1, (left, right) as x/z and (top, bottom) as y/z; near: metres."""

    viewmat: np.ndarray
    tan_x: tuple[float, float]
    tan_y: tuple[float, float]
    near: float = 0.01

    @classmethod
    def from_camera(cls, viewmat, K, width: int, height: int, near: float = 0.01):
        """The frustum of intrinsics K (pixels, centres at +0.5) over a width x height image."""
        K = np.asarray(K, np.float64)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        return cls(
            viewmat=np.asarray(viewmat, np.float64),
            tan_x=(float(-cx / fx), float((width - cx) / fx)),
            tan_y=(float(-cy / fy), float((height - cy) / fy)),
            near=float(near),
        )

    def key(self) -> tuple:
        """A hashable summary for cache keys: the camera to 0.1 mm and 1e-6 in angle."""
        return (
            tuple(np.round(self.viewmat[:3].ravel(), 4).tolist()),
            tuple(np.round(self.tan_x + self.tan_y, 6).tolist()),
            self.near,
        )

    def visible(self, points: np.ndarray, reaches: np.ndarray) -> np.ndarray:
        """Mask over points (3, N) of those whose sphere of radius `reaches` (N,) meets the
        frustum (tested plane by plane: conservative near the frustum's edges)."""
        R = self.viewmat[:3, :3].astype(np.float32)
        x, y, z = R @ points + self.viewmat[:3, 3].astype(np.float32)[:, None]
        keep = z > self.near - reaches
        for coord, (low, high) in ((x, self.tan_x), (y, self.tan_y)):
            # signed distances to the two side planes through the camera centre, outwards
            keep &= (low * z - coord) / np.hypot(1.0, low) < reaches
            keep &= (coord - high * z) / np.hypot(1.0, high) < reaches
        return keep
