"""The method's real LOD cost: the continuous model against dedicated single-resolution
models, one subject and one budget.

    python benchmarks/lod_cost.py --data out/synth_track --out out/lod_cost
        [--config cpu] [--steps 600,900] [--avatar '{"colour_space": "display"}']

Trains, with the project's training command and the same stage-1 and stage-2 step counts,
the continuous model of the config and one dedicated model per count, S_max, the middle
level's S and S_min, each trained only at that count (`"s_max" = "s_min" = S`, one level
per stage-2 step: a fixed level gains nothing from more). Runs already finished in --out are
kept (a killed benchmark resumes them). Evaluates every model on its test frames and prints
per level the continuous model's PSNR minus the dedicated model's, and the dedicated models'
own drop from S_max to S_min (how sensitive the subject is to the count).
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
from pathlib import Path

from archhead_addon.avatar.lod import resolution_for_lod
from archhead_addon.train.config import config_data

LODS = (0.0, 0.5, 1.0)


def configs(base: dict, steps: tuple[int, int], avatar: dict) -> dict[str, dict]:
    """{run name: config}: "continuous" and "S<n>" per dedicated count."""
    # the method's two stages alone (stages 3 and 4 train the continuous run's feature field)
    base = {**base, "stage1_steps": steps[0], "stage2_steps": steps[1]}
    base |= {"stage3_steps": 0, "stage4_steps": 0}
    base["avatar"] = {**base.get("avatar", {}), **avatar}
    s_max, s_min = base["avatar"].get("s_max", 256), base["avatar"].get("s_min", 64)
    out = {"continuous": base}
    for lod in LODS:
        s = resolution_for_lod(lod, s_max, s_min)[1]
        out[f"S{s}"] = {
            **base,
            "lods_per_step": 1,
            "avatar": {**base["avatar"], "s_max": s, "s_min": s},
        }
    return out


def _python(*args: str) -> None:
    subprocess.run([sys.executable, *args], check=True)


def train_and_score(name: str, config: dict, data: Path, out: Path, lods) -> dict[float, dict]:
    """{lod: metrics row} of one run, trained (or resumed, or kept when finished) and
    evaluated."""
    run, evaluation = out / name, out / f"{name}_eval"
    total = config["stage1_steps"] + config["stage2_steps"]
    manifest = run / "checkpoint.json"
    done = manifest.is_file() and json.loads(manifest.read_text()).get("step") == total
    if not done:
        config_file = out / f"{name}.json"
        config_file.write_text(json.dumps(config, indent=1))
        resume = ["--resume"] if manifest.is_file() else ["--config", str(config_file)]
        _python("-m", "archhead_addon.train", "--data", str(data), "--out", str(run), *resume)
    levels = ",".join(f"{lod:g}" for lod in lods)
    _python(
        "-m", "archhead_addon.evaluate", "--avatar", str(run / "avatar.npz"),
        "--data", str(data), "--out", str(evaluation), "--lods", levels, "--precisions", "fp32",
    )  # fmt: skip
    with open(evaluation / "metrics.csv") as f:
        return {float(row["lod"]): row for row in csv.DictReader(f)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--config", default="cpu", help="preset or config file (base)")
    parser.add_argument("--steps", default="600,900", help="stage-1,stage-2 steps of every run")
    parser.add_argument("--avatar", default="{}", help="AvatarConfig fields (JSON) for every run")
    args = parser.parse_args(argv)
    steps = tuple(int(x) for x in args.steps.split(","))
    runs = configs(config_data(args.config), steps, json.loads(args.avatar))
    args.out.mkdir(parents=True, exist_ok=True)
    continuous = train_and_score("continuous", runs.pop("continuous"), args.data, args.out, LODS)
    print(f"\n{args.data}: {steps[0]} + {steps[1]} steps per run, test PSNR (dB)\n")
    print("| l | S (Gaussians) | dedicated | continuous | continuous - dedicated |")
    print("|---:|---:|---:|---:|---:|")
    dedicated = {}
    for lod, (name, config) in zip(LODS, runs.items(), strict=True):
        row = train_and_score(name, config, args.data, args.out, (0.0,))[0.0]
        dedicated[lod] = float(row["psnr"])
        mine = float(continuous[lod]["psnr"])
        print(
            f"| {lod:g} | {row['uv_resolution']} ({int(row['gaussians']):,}) "
            f"| {dedicated[lod]:.2f} | {mine:.2f} | {mine - dedicated[lod]:+.2f} |"
        )
    drop = dedicated[1.0] - dedicated[0.0]
    print(
        f"\nDedicated models from S_max to S_min: {drop:+.2f} dB "
        f"({100 * drop / dedicated[0.0]:+.1f} %)."
    )


if __name__ == "__main__":
    main()
