"""A tiny synthetic subject (Cycles through bpy, ~5 s) and a tiny training config, shared by
the training and evaluation tests; rendered once per test session."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
FRAMES, SIZE = 8, 48
TINY_CONFIG = {
    "resolution": SIZE,
    "stage1_steps": 24,
    "stage2_steps": 8,
    "lods_per_step": 2,
    "lpips_every": 2,
    "checkpoint_every": 4,
    "lr": {"features": 0.01, "mapping": 0.003, "decoder": 0.005},
    "avatar": {
        "s_max": 32,
        "s_min": 8,
        "levels": [32, 16, 8],
        "feature_dim": 8,
        "hidden": 16,
        "colour_hidden": 16,
        "mapping_hidden": 16,
    },
}


def tiny_subject(tmp_path_factory) -> Path:
    """8 frames of 48x48 px: 7 train, 1 test."""
    folder = tmp_path_factory.getbasetemp() / "tiny_subject"
    if not (folder / "tracking.npz").exists():
        subprocess.run(
            [
                sys.executable,
                str(REPO_ROOT / "scripts" / "synthetic_subject.py"),
                "--out",
                str(folder),
                "--frames",
                str(FRAMES),
                "--size",
                str(SIZE),
                "--samples",
                "8",
            ],
            check=True,
            capture_output=True,
            timeout=300,
        )
    return folder


def write_config(path: Path, **changes) -> Path:
    path.write_text(json.dumps({**TINY_CONFIG, **changes}))
    return path
