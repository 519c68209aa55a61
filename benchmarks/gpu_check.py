"""The GPU path checked and timed on a CUDA machine, in one command (docs/gpu.md):

    python benchmarks/gpu_check.py --data DIR [--out gpu_check.md] [--minutes 0]
        [--presets cpu,gpu_paper] [--steps 100] [--score RUN]

1. builds gsplat's CUDA kernels if needed (its first use compiles them) and times that;
2. runs the GPU tests (`tests/test_splat_gpu.py`; the rest of the suite needs Blender's bpy);
3. compares gsplat with the CPU kernel on face scenes, forward (images) and backward (the
   gradient of a fixed random image loss for every parameter: cosine and relative norm);
4. with `--score RUN`, scores a finished run (a CPU-trained avatar) as the quality ladder's
   rungs c and d on this device, the reference beside the GPU run's rows;
5. times stage-1 and stage-2 training steps of each preset on DIR (a tracked folder), from
   the training command's own `--progress-json` (seconds per step over each stage's
   `--steps` steps, the first fifth dropped as warm-up) and the whole preset from them;
6. profiles one stage-2 step of the last preset with torch.profiler: the time the host
   spends against the time the GPU is busy;
7. with `--minutes M`, trains `gpu_paper` shortened to about M minutes and scores it as the
   quality ladder's rungs c (training frames) and d (held-out frames), head and all.
Writes one Markdown file (--out) naming the card, line by line as results come, and prints
them; runs and scores go to the folder beside it (--out without its suffix). Refuses clearly
without CUDA. A GPU-less machine has nothing here to measure: the CPU figures are in
docs/results.md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

FACE_SCENES = ((2_000, 128), (20_000, 256), (60_000, 512))  # Gaussians, image side
GPU_TESTS = "tests/test_splat_gpu.py"


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, help="a tracked folder for the step timings (4-6)")
    p.add_argument("--out", type=Path, default=Path("gpu_check.md"), help="the Markdown file")
    p.add_argument("--presets", default="cpu,gpu_paper", help="presets to time (comma list)")
    p.add_argument("--steps", type=int, default=100, help="steps timed per stage and preset")
    p.add_argument("--minutes", type=float, default=0.0, help="a shortened gpu_paper run")
    p.add_argument(
        "--score", type=Path, help="a finished training run to score here beside the GPU's"
    )
    return p.parse_args(argv)


def build_gsplat() -> float:
    """Seconds for gsplat's first rasterization (its JIT build when not cached)."""
    import torch
    from gsplat import rasterization

    start = time.monotonic()
    dev = torch.device("cuda")
    means = torch.tensor([[0.0, 0.0, 1.0]], device=dev)
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], device=dev)
    scales = torch.full((1, 3), 0.01, device=dev)
    K = torch.tensor([[50.0, 0, 16], [0, 50.0, 16], [0, 0, 1]], device=dev)
    rasterization(
        means,
        quats,
        scales,
        torch.ones(1, device=dev),
        torch.ones(1, 3, device=dev),
        torch.eye(4, device=dev)[None],
        K[None],
        32,
        32,
    )
    torch.cuda.synchronize()
    return time.monotonic() - start


def compare_backends(n: int, side: int) -> dict:
    """Forward and backward of gsplat against the CPU kernel on one face scene."""
    import torch

    from archhead_addon.splat import rasterize_frame, scenes

    scene = scenes.face_scene(n, width=side, height=side, seed=3)
    weights = torch.rand(side, side, 3, generator=torch.Generator().manual_seed(4))
    out = {}
    for backend, device in (("cpu", "cpu"), ("gsplat", "cuda")):
        frame = scene.gaussians.map(lambda a, d=device: torch.tensor(a, device=d))
        frame = frame.map(lambda t: t.requires_grad_(True) if t.is_floating_point() else t)
        image = rasterize_frame(frame, scene.viewmat, scene.K, side, side, backend=backend)
        (image.rgb * weights.to(device)).sum().backward()
        grads = {
            k: v.grad.detach().cpu().double().flatten()
            for k, v in frame.arrays().items()
            if isinstance(v, torch.Tensor) and v.grad is not None
        }
        out[backend] = (image.rgb.detach().cpu(), grads)
    (cpu_img, cpu_g), (gpu_img, gpu_g) = out["cpu"], out["gsplat"]
    cosines = {
        k: float(torch.nn.functional.cosine_similarity(cpu_g[k], gpu_g[k], dim=0)) for k in cpu_g
    }
    return {
        "scene": f"{n:,} Gaussians, {side}²",
        "image_max_abs": float((cpu_img - gpu_img).abs().max()),
        "grad_cosine_min": min(cosines.values()),
        "grad_cosines": cosines,
    }


def _train_command(data: Path, out: Path, config: Path) -> list[str]:
    train = [sys.executable, "-m", "archhead_addon.train", "--data", str(data)]
    return train + ["--out", str(out), "--config", str(config)]


def time_preset(data: Path, preset: str, steps: int) -> dict:
    """Milliseconds per step of each stage, from a short run's progress events."""
    from archhead_addon.train.config import TrainConfig

    config = json.loads(TrainConfig.load(preset).to_json())
    for k in range(1, 5):  # each stage the preset has, `steps` long
        if k < 3 or config[f"stage{k}_steps"]:
            config[f"stage{k}_steps"] = steps
    config.update(checkpoint_every=10 * steps)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "config.json"
        path.write_text(json.dumps(config))
        command = _train_command(data, Path(folder) / "run", path) + ["--progress-json"]
        done = subprocess.run(command, capture_output=True, text=True, check=True)
    marks = {k: [] for k in range(1, 5)}  # (step, elapsed seconds) of each stage's steps
    for line in done.stdout.splitlines():
        event = json.loads(line) if line.startswith("{") else {}
        if event.get("event") == "step":
            marks[event["stage"]].append((event["step"], event["elapsed_seconds"]))
    out = {}
    for stage, points in marks.items():
        points = points[max(len(points) // 5, 1) :]  # warm-up steps: allocation, autotuning
        if len(points) >= 2:  # elapsed is given to 0.1 s: time a stretch of steps
            (s0, t0), (s1, t1) = points[0], points[-1]
            out[f"stage{stage}_ms"] = 1e3 * (t1 - t0) / max(s1 - s0, 1)
    return out


def profile_stage2(data: Path, preset: str, device: str = "cuda") -> dict:
    """One stage-2 step under torch.profiler: host (CPU) time against GPU-busy time."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    from archhead_addon.flame.model import load_model
    from archhead_addon.train import loop
    from archhead_addon.train.config import TrainConfig
    from archhead_addon.train.dataset import FrameDataset

    config = TrainConfig.load(preset)
    device = torch.device(device)
    model = load_model(None)
    dataset = FrameDataset(data, config.resolution, model, split="train", frames=8)
    frames = loop.frames_on_device(dataset, device)
    with tempfile.TemporaryDirectory() as folder:
        trainer = loop.Trainer.create(
            config, frames, model, dataset.sequence.shape[0], folder, dataset.background, device
        )
        trainer.step = config.stage1_steps  # a stage-2 step
        for _ in range(3):
            trainer.train_step()  # warm-up
        cuda = device.type == "cuda"
        sync = torch.cuda.synchronize if cuda else (lambda: None)
        sync()
        activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
        with profile(activities=activities) as prof:
            start = time.perf_counter()
            trainer.train_step()
            sync()
            wall = time.perf_counter() - start
    events = prof.key_averages()
    gpu_us = sum(getattr(e, "self_device_time_total", 0.0) for e in events) if cuda else 0.0
    return {
        "step_ms": 1e3 * wall,
        "gpu_busy_ms": gpu_us / 1e3,
        "host_share": max(0.0, 1 - gpu_us / 1e3 / (1e3 * wall)),
    }


def short_run(data: Path, minutes: float, out: Path, rates: dict | None = None) -> dict:
    """gpu_paper shortened to about `minutes` (from its measured step times), scored as the
    quality ladder's rungs c and d (benchmarks/quality_ladder.py, its table)."""
    from archhead_addon.train.config import TrainConfig

    config = json.loads(TrainConfig.load("gpu_paper").to_json())
    rates = rates or time_preset(data, "gpu_paper", 20)
    per_pair = rates["stage1_ms"] + 2 * rates["stage2_ms"]  # the preset's 1:2 stage ratio
    n = max(int(minutes * 60e3 / per_pair), 10)
    config.update(stage1_steps=n, stage2_steps=2 * n, holdout="interleaved")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "gpu_paper_short.json"
    path.write_text(json.dumps(config))
    start = time.monotonic()
    subprocess.run(_train_command(data, out / "run_all", path), check=True)
    train_s = time.monotonic() - start
    return {"steps": 3 * n, "train_s": train_s, "ladder": _ladder_rows(data, out)}


def score_run(data: Path, run: Path, out: Path) -> str:
    """A finished run (its avatar.npz, checkpoint.json and config.json; a CPU-trained one)
    scored as the quality ladder's rungs c and d on this device, beside the GPU run's rows."""
    (out / "run_all").mkdir(parents=True, exist_ok=True)
    for name in ("avatar.npz", "checkpoint.json", "config.json"):
        shutil.copyfile(run / name, out / "run_all" / name)
    return _ladder_rows(data, out)


def _ladder_rows(data: Path, out: Path) -> str:
    """The ladder table of the run in out/run_all (benchmarks/quality_ladder.py)."""
    ladder = Path(__file__).with_name("quality_ladder.py")
    subprocess.run(
        [sys.executable, str(ladder), "--data", str(data), "--out", str(out), "--score-only"],
        check=True,
    )
    return (out / "ladder.md").read_text()


def main(argv=None) -> int:
    args = parse_args(argv)
    import torch

    from archhead_addon.train.config import TrainConfig

    if not torch.cuda.is_available():
        print(
            "gpu_check: no CUDA device is visible to torch here; run it on a machine with an "
            "NVIDIA GPU (docs/gpu.md)",
            file=sys.stderr,
        )
        return 2
    lines = []
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def emit(*new: str) -> None:
        """Print and keep each result as it comes: a run cut short keeps what it measured."""
        lines.extend(new)
        print("\n".join(new), flush=True)
        args.out.write_text("\n".join(lines) + "\n")

    card = torch.cuda.get_device_name(0)
    emit(f"# GPU check on {card}", "", f"torch {torch.__version__}, CUDA {torch.version.cuda}")
    emit("", f"gsplat first rasterization (build if needed): {build_gsplat():.1f} s")
    tests = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-m", "gpu", GPU_TESTS],
        capture_output=True,
        text=True,
    )
    emit(f"GPU tests: {(tests.stdout.strip().splitlines() or ['no output'])[-1]}", "")
    emit("| scene | image max abs diff | gradient cosine, lowest parameter |", "|---|---:|---:|")
    for n, side in FACE_SCENES:
        c = compare_backends(n, side)
        emit(f"| {c['scene']} | {c['image_max_abs']:.2e} | {c['grad_cosine_min']:.5f} |")
    if args.data is None:
        return 0
    folder = args.out.with_suffix("")
    if args.score is not None:
        ladder = score_run(args.data, args.score, folder / "scored")
        emit("", f"{args.score} scored here:", "", ladder)
    emit(
        "", "| preset | stage 1 ms/step | stage 2 ms/step | whole preset |", "|---|---:|---:|---:|"
    )
    presets, timed = args.presets.split(","), {}
    for preset in presets:
        t = timed[preset] = time_preset(args.data, preset, args.steps)
        s1, s2 = t.get("stage1_ms", 0), t.get("stage2_ms", 0)
        config = TrainConfig.load(preset)
        rates = [t.get(f"stage{k}_ms", 0) for k in range(1, 5)]
        whole = sum(n * ms for n, ms in zip(config.stage_steps, rates, strict=True)) / 60e3
        emit(f"| {preset} | {s1:.1f} | {s2:.1f} | {whole:.1f} min |")
    p = profile_stage2(args.data, presets[-1])
    emit(
        "",
        f"One {presets[-1]} stage-2 step: {p['step_ms']:.1f} ms, "
        f"GPU busy {p['gpu_busy_ms']:.1f} ms (host share {100 * p['host_share']:.0f} %)",
    )
    if args.minutes > 0:
        r = short_run(args.data, args.minutes, folder / "gpu_paper_short", timed.get("gpu_paper"))
        emit(
            "",
            f"gpu_paper shortened to {r['steps']:,} steps ({r['train_s'] / 60:.1f} min):",
            "",
            r["ladder"],
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
