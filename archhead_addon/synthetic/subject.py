"""The synthetic subject's output folder: paths, frame and mask files, tracking, summary."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..io.atomic import write_bytes_atomic
from ..sequences import Sequence, write_canonical
from .png import encode_png

FRAMES_DIR, MASKS_DIR, TRACKING_FILE = "frames", "masks", "tracking.npz"
_OUR_NAMES = re.compile(r"^\d{5}\.png$")


def frame_name(index: int) -> str:
    return f"{index:05d}.png"


class SubjectFolder:
    """OUT/frames/00000.png, OUT/masks/00000.png, OUT/tracking.npz (see the package doc)."""

    def __init__(self, root):
        self.root = Path(root)
        self.frames = self.root / FRAMES_DIR
        self.masks = self.root / MASKS_DIR
        self.tracking = self.root / TRACKING_FILE

    def prepare(self) -> None:
        """Create the folders and delete frames and masks of an earlier run (only our own
        names), so a shorter rerun never leaves more frames than its tracking has."""
        for folder in (self.frames, self.masks):
            folder.mkdir(parents=True, exist_ok=True)
            for path in folder.iterdir():
                if _OUR_NAMES.match(path.name):
                    path.unlink()

    def write_tracking(self, seq: Sequence) -> None:
        write_canonical(seq, self.tracking)

    def write_frame(self, index: int, rgba: np.ndarray) -> None:
        """Split a straight-alpha render (H,W,4) uint8, top row first, into frame and mask.

        Colour under zero alpha means nothing (renderers leave black or garbage): it is
        written as black so the files do not depend on the renderer's choice."""
        rgba = np.asarray(rgba)
        if rgba.dtype != np.uint8 or rgba.ndim != 3 or rgba.shape[2] != 4:
            raise ValueError(f"expected (H,W,4) uint8, found {rgba.dtype} {rgba.shape}")
        rgb = np.where(rgba[..., 3:] > 0, rgba[..., :3], 0).astype(np.uint8)
        write_bytes_atomic(self.frames / frame_name(index), encode_png(rgb))
        write_bytes_atomic(self.masks / frame_name(index), encode_png(rgba[..., 3]))

    def summary(self, n_frames: int, size: int, samples: int, seconds: float) -> str:
        per_frame = seconds / max(n_frames, 1)
        return (
            f"synthetic subject: {n_frames} frames of {size}x{size} px, {samples} samples, "
            f"{seconds:.1f} s ({per_frame:.2f} s per frame)\n"
            f"  frames   {self.frames}/{frame_name(0)} ...\n"
            f"  masks    {self.masks}/{frame_name(0)} ...\n"
            f"  tracking {self.tracking}"
        )
