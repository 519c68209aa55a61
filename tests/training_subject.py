"""The tiny synthetic subject's size and a tiny training config, shared by the training and
evaluation tests (the subject itself: the `tiny_subject` fixture, tests/conftest.py)."""

from __future__ import annotations

import json
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


def write_config(path: Path, **changes) -> Path:
    path.write_text(json.dumps({**TINY_CONFIG, **changes}))
    return path
