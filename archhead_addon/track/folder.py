"""The tracker's output: a training data folder, complete or absent.

It holds frames/, masks/ (head and neck, `head_mask`), masks_person/ (the whole person, for
avatars with shoulders), tracking.npz and tracking_report.json. There is no parts/: the
training dataset rasterizes the eye/mouth mask B from the tracked mesh at the training size
(`train.parts_mask`), the same function the tracker would call, exact at any resolution.

Everything is written into a temporary sibling of OUT (`OUT.partial-*`) that is renamed to
OUT only when complete, so a failed or killed run never leaves a half-written folder behind
(an earlier OUT is replaced only at that moment). Names follow `train.dataset`.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..io.atomic import write_bytes_atomic
from ..synthetic.png import encode_png
from ..train.dataset import FRAMES_DIR, MASKS_DIR, PERSON_MASKS_DIR

REPORT_FILE = "tracking_report.json"


@contextlib.contextmanager
def staged_folder(out) -> Iterator[Path]:
    """A fresh temporary folder beside `out`, moved to `out` when the block succeeds."""
    out = Path(out).absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    for stale in out.parent.glob(f"{out.name}.partial-*"):  # from killed runs
        shutil.rmtree(stale, ignore_errors=True)
    stage = Path(tempfile.mkdtemp(prefix=f"{out.name}.partial-", dir=out.parent))
    try:
        for name in (FRAMES_DIR, MASKS_DIR, PERSON_MASKS_DIR):
            (stage / name).mkdir()
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    os.chmod(stage, 0o755)  # mkdtemp makes it private; a data folder is shared like others
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f"{out.name}.old-", dir=out.parent))
        os.replace(out, old / out.name)
        os.replace(stage, out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(stage, out)


def frame_name(number: int) -> str:
    return f"{number:05d}.png"


def write_frame(stage: Path, number: int, rgb: np.ndarray) -> None:
    """RGB uint8 (H,W,3) into frames/."""
    write_bytes_atomic(stage / FRAMES_DIR / frame_name(number), encode_png(rgb, level=1))


def write_mask(folder: Path, number: int, mask: np.ndarray) -> None:
    """A mask as floats in [0, 1] (H,W), as 8-bit grey."""
    grey = np.round(np.clip(mask, 0, 1) * 255).astype(np.uint8)
    write_bytes_atomic(folder / frame_name(number), encode_png(grey, level=1))


def write_report(stage: Path, report: dict) -> None:
    write_bytes_atomic(stage / REPORT_FILE, json.dumps(report, indent=1).encode())
