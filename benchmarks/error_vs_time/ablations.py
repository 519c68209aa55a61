"""The ablations of the paper's table 4: the avatar without a feature map and with a single
map of 64, 128 or 256, each trained with the same config and the same number of steps as the
full multi-level field, by the project's training command in a child process."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

from archhead_addon.backend_process import train_command
from archhead_addon.timing import Stopwatch
from archhead_addon.train.config import TrainConfig
from archhead_addon.train.run_folder import RunFolder

VARIANTS = {
    "full (multi-level)": None,
    "no feature map": [],
    "single map 64": [64],
    "single map 128": [128],
    "single map 256": [256],
}


def variant_config(base: TrainConfig, levels: list[int] | None, steps: int) -> dict:
    """`base` with the feature levels replaced (None keeps them) and `steps` split between
    the stages in the base's proportion."""
    config = asdict(base)
    if levels is not None:
        config["avatar"] = {**config["avatar"], "levels": levels}
    stage1 = math.ceil(steps * base.stage1_steps / base.total_steps)
    # stages 3 and 4 train the feature field: none without one
    later = [
        0 if levels == [] else math.floor(steps * n / base.total_steps)
        for n in base.stage_steps[2:]
    ]
    config["stage1_steps"], config["stage3_steps"], config["stage4_steps"] = stage1, *later
    config["stage2_steps"] = steps - stage1 - sum(later)
    config["checkpoint_every"] = max(steps, 1)
    return config


def train_variants(
    base: TrainConfig, steps: int, data: Path, out: Path, python: str = sys.executable
) -> dict[str, tuple[Path, float]]:
    """{variant: (avatar checkpoint, training seconds)}; a variant's earlier run in its folder
    is replaced; its log goes to train.log there."""
    done = {}
    for name, levels in VARIANTS.items():
        folder = out / name.split(" (")[0].replace(" ", "_")
        run = RunFolder(folder)
        run.clear_checkpoints()
        folder.mkdir(parents=True, exist_ok=True)
        config = folder / "ablation_config.json"
        config.write_text(json.dumps(variant_config(base, levels, steps)))
        watch = Stopwatch()
        with open(run.log, "w") as log:
            subprocess.run(
                train_command(python, data, folder, config),
                check=True,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        done[name] = (run.avatar, watch.seconds)
    return done
