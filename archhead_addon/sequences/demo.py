"""A deterministic talking-head trajectory for the demo, benchmarks and tests."""

from __future__ import annotations

import numpy as np

from .sequence import Sequence


def demo_sequence(
    frames: int = 120,
    n_shape: int = 300,
    n_expr: int = 100,
    fps: float = 30.0,
    image_size: tuple[int, int] = (512, 512),
    distance: float = 0.7,
) -> Sequence:
    """Smooth expressions decaying over components, jaw talking, a nodding, turning head,
    glancing eyes, and a fixed camera `distance` metres in front of the face."""
    t = np.arange(frames) / fps
    rng = np.random.default_rng(7)
    phases = rng.uniform(0, 2 * np.pi, size=(1, n_expr))
    rates = rng.uniform(0.5, 2.0, size=(1, n_expr))
    expr = 1.5 * np.sin(t[:, None] * rates + phases) * np.exp(-np.arange(n_expr) / 15)
    talk = np.clip(np.sin(t * 7.0) * np.sin(t * 1.7), 0, None)
    zeros = np.zeros(frames)
    jaw = np.stack([0.25 * talk, zeros, zeros], 1)
    neck = np.stack([0.12 * np.sin(t * 0.9), 0.35 * np.sin(t * 0.6), zeros], 1)
    glance = 0.25 * np.sin(t * 1.1)
    eyes = np.stack([zeros, glance, zeros, zeros, glance, zeros], 1)
    rotation = np.stack([0.05 * np.sin(t * 0.5), zeros, zeros], 1)
    f = 2.2 * image_size[1]  # a ~25 degree field of view
    K = np.array([[f, 0, image_size[1] / 2], [0, f, image_size[0] / 2], [0, 0, 1]])
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, 1, 1] = w2c[:, 2, 2] = -1  # camera on +z looking at the face (-z), y down
    w2c[:, 2, 3] = distance
    return Sequence(
        shape=np.zeros((frames, n_shape)),
        expr=expr,
        jaw=jaw,
        neck=neck,
        eyes=eyes,
        rotation=rotation,
        translation=np.zeros((frames, 3)),
        fps=fps,
        frame_ids=np.arange(frames),
        source="demo",
        format="canonical",
        K=np.tile(K, (frames, 1, 1)),
        w2c=w2c,
        image_size=image_size,
    )
