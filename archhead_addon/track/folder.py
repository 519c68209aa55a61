"""The tracker's output: a training data folder, complete or absent.

It holds frames/, masks/ (head and neck, `head_mask`), regions/ (the region that cut the
person to head and neck, from the tracked mesh alone: training cuts its renders to it),
masks_person/ (the whole person, for avatars with shoulders), tracking.npz and
tracking_report.json. There is no parts/: the training dataset rasterizes the eye/mouth mask B
from the tracked mesh at the training size (`train.parts_mask`), the same function the tracker
would call, exact at any resolution.

Everything is written into a temporary sibling of OUT (`OUT.partial-*`) that is renamed to
OUT only when complete, so a failed or killed run never leaves a half-written folder behind
(an earlier OUT is replaced only at that moment). A kill -9 leaves the stage itself: the next
run into the same parent folder removes it, whatever its OUT, once its process is gone.
Names follow `train.dataset`.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ..io.atomic import write_bytes_atomic
from ..synthetic.png import encode_png
from ..train.dataset import FRAMES_DIR, MASKS_DIR, PERSON_MASKS_DIR, REGIONS_DIR

REPORT_FILE = "tracking_report.json"


OWNER_FILE = ".owner"  # a stage's process id: a stage whose process is gone is stale


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def remove_stale_stages(parent: Path) -> list[Path]:
    """Remove the `*.partial-*` folders in `parent` that killed runs left, whatever their
    OUT; a stage whose process still runs (another tracking into the same folder) stays."""
    removed = []
    for stage in parent.glob("*.partial-*"):
        try:
            pid = int((stage / OWNER_FILE).read_text())
        except (OSError, ValueError):
            pid = None  # no owner yet (just made) or an older layout: judged by age
            if time.time() - stage.stat().st_mtime < 60:
                continue
        if pid is None or not _alive(pid):
            shutil.rmtree(stage, ignore_errors=True)
            removed.append(stage)
    return removed


def new_stage(parent: Path, name: str) -> Path:
    """A fresh `name.partial-*` folder in `parent` owned by this process: a kill -9 leaves it
    for `remove_stale_stages` (call that first) of the next run into `parent`."""
    stage = Path(tempfile.mkdtemp(prefix=f"{name}.partial-", dir=parent))
    (stage / OWNER_FILE).write_text(str(os.getpid()))
    return stage


@contextlib.contextmanager
def staged_folder(out) -> Iterator[Path]:
    """A fresh temporary folder beside `out`, moved to `out` when the block succeeds."""
    out = Path(out).absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_stages(out.parent)
    stage = new_stage(out.parent, out.name)
    try:
        for name in (FRAMES_DIR, MASKS_DIR, PERSON_MASKS_DIR, REGIONS_DIR):
            (stage / name).mkdir()
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    (stage / OWNER_FILE).unlink()
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
