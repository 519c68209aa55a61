"""The benchmarks outside the package: every benchmark command the README and docs/ name
exists where they say, and the splat kernel benchmark prints its table."""

import os
import re
import subprocess
import sys

import pytest

# `python benchmarks/x.py`, `python scripts/x.py`, `python -m some.module`, as documented
SCRIPT = re.compile(r"python (?:-m )?((?:benchmarks|scripts)/[\w/]+\.py)")
MODULE = re.compile(r"python -m\s+([\w.]+)")


def _benchmark(repo_root, script, *args, env=None) -> str:
    """The standard output of `python benchmarks/<script> ARGS` run from the repository."""
    return subprocess.run(
        [sys.executable, f"benchmarks/{script}", *map(str, args)],
        cwd=repo_root,
        env=env,
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    ).stdout


def _documents(repo_root):
    return [repo_root / "README.md", *sorted((repo_root / "docs").glob("*.md"))]


def test_documented_commands_name_existing_files_and_modules(repo_root):
    import importlib.util

    seen = set()
    for doc in _documents(repo_root):
        text = doc.read_text()
        for path in SCRIPT.findall(text):
            assert (repo_root / path).is_file(), f"{doc.name}: {path}"
            seen.add(path)
        for module in MODULE.findall(text):
            module = module.rstrip(".")
            if module.startswith(("archhead_addon", "benchmarks")):
                assert importlib.util.find_spec(module) is not None, f"{doc.name}: {module}"
                seen.add(module)
    assert {"benchmarks/splat_kernel.py", "benchmarks/avatar_decode.py"} <= seen
    assert "benchmarks.error_vs_time" in seen
    assert not any(m.startswith("archhead_addon.bench") or m.endswith(".bench") for m in seen)


@pytest.mark.parametrize("extra", [["--no-torch"]])
def test_splat_kernel_benchmark_prints_its_table(repo_root, extra):
    out = _benchmark(repo_root, "splat_kernel.py", "--quick", "--repeats", "1", *extra)
    rows = [line for line in out.splitlines() if line.startswith("| 3,000 | 256²")]
    assert len(rows) == 1 and "Times in ms" in out


def test_splat_versions_benchmark_prints_its_tables(repo_root):
    """Quick scene, no earlier revision; OpenSplat is skipped without a checkout."""
    env = {k: v for k, v in os.environ.items() if k != "ARCHHEAD_OPENSPLAT"}
    out = _benchmark(
        repo_root, "splat_versions.py", "--quick", "--repeats", 1, "--before", "none", env=env
    )
    assert "OpenSplat: skipped" in out
    assert sum(line.startswith("| now, ") for line in out.splitlines()) >= 1
    assert "| used / limit |" in out


def test_splat_fill_replays_the_kernels_lanes(repo_root):
    """The fill oracle's replay of the compositing uses the lanes the kernel used (its
    float64 alpha test may differ from the kernel's float32 one at the threshold)."""
    from archhead_addon.splat import kernel, scenes

    scene = scenes.face_scene(3_000, 128, 128, seed=0)
    ctx = kernel.forward(scene.gaussians.checked(), scene.settings(num_threads=1))[1]
    kernel_used = ctx.stats()["lanes_used"]
    out = _benchmark(repo_root, "splat_fill.py", "--gaussians", 3_000, "--size", 128)
    used = int(re.search(r"Lanes used \(all geometries\): ([\d,]+)", out)[1].replace(",", ""))
    assert abs(used - kernel_used) <= 1e-4 * kernel_used, (used, kernel_used)
    rows = re.findall(r"^\| [^|]+ \| ([\d,]+) \| (\d+)% \|$", out, re.M)
    assert len(rows) == 8
    assert all(used <= int(n.replace(",", "")) and 0 < int(share) <= 100 for n, share in rows)


def test_training_profile_prints_both_versions_of_both_stages(repo_root, tiny_subject, tmp_path):
    from training_subject import write_config

    config = write_config(tmp_path / "tiny.json", stage1_steps=2, stage2_steps=2)
    out = _benchmark(
        repo_root, "training_profile.py", "--data", tiny_subject, "--config", config,
        "--steps", 1, "--threads", 1,
    )  # fmt: skip
    rows = [line.split("|")[1:3] for line in out.splitlines() if line.startswith("| 1 |")]
    rows += [line.split("|")[1:3] for line in out.splitlines() if line.startswith("| 2 |")]
    assert [(s.strip(), v.strip()) for s, v in rows] == [
        ("1", "before"),
        ("1", "after"),
        ("2", "before"),
        ("2", "after"),
    ]
    assert re.search(r"stage 1: step [\d.]+x .* resample [\d.]+x", out)
    saved = re.search(r"a checkpoint: (\d+) ms, ([\d.]+) MB written", out)
    assert saved and float(saved[2]) > 0.1  # the avatar and the training state, at least


def test_step_changes_times_every_variant_against_the_step_before(
    repo_root, tiny_subject, tmp_path
):
    from training_subject import write_config

    config = write_config(tmp_path / "tiny.json", stage1_steps=4, stage2_steps=4)
    out = _benchmark(
        repo_root, "step_changes.py", "--data", tiny_subject, "--config", config,
        "--blocks", 1, "--steps", 2, "--warm", 1,
    )  # fmt: skip
    rows = [line.split("|")[1:6] for line in out.splitlines() if re.match(r"\| [12] \|", line)]
    assert [(r[0].strip(), r[1].strip()) for r in rows] == [
        (s, v) for s in "12" for v in ("before", "tables", "pose", "adam", "after")
    ]
    assert all(r[4].strip() == "1.000x" for r in rows if r[1].strip() == "before")
    assert all(float(r[3]) > 0 for r in rows)


def test_tracking_changes_times_both_forms_of_each_part(repo_root, tiny_subject):
    out = _benchmark(
        repo_root, "tracking_changes.py", "--data", tiny_subject, "--frames", 2, "--repeat", 1
    )
    parts = ("masks", "refine points", "landmark fit step", "refine pose")
    rows = [line.split("|")[1:5] for line in out.splitlines() if line.startswith("| ")]
    rows = [r for r in rows if r[0].strip() in parts]
    versions = {"refine points": ("before", "three gathers", "after")}
    assert [(r[0].strip(), r[1].strip()) for r in rows] == [
        (part, version) for part in parts for version in versions.get(part, ("before", "after"))
    ]
    assert all(float(r[2]) > 0 for r in rows)
    assert all(r[3].strip() == "1.00x" for r in rows if r[1].strip() == "before")


def test_later_stages_continue_a_finished_run_and_score_each_variant(
    repo_root, tiny_subject, tmp_path
):
    from training_subject import write_config

    from archhead_addon.train.__main__ import main as train
    from benchmarks.later_stages import VARIANTS

    run, config = tmp_path / "run", write_config(tmp_path / "tiny.json")
    assert train(["--data", str(tiny_subject), "--out", str(run), "--config", str(config)]) == 0
    staged = write_config(tmp_path / "staged.json", stage3_steps=2, stage4_steps=3)
    out = _benchmark(
        repo_root, "later_stages.py", "--run", run, "--data", tiny_subject, "--out",
        tmp_path / "later", "--steps", 2, "--preset", staged, "--lods", "0,0.5,0.9,0.95,1",
    )  # fmt: skip
    rows = [line.split("|")[1:-1] for line in out.splitlines()[2:]]
    assert [r[0].strip() for r in rows] == list(VARIANTS)
    psnr = {r[0].strip(): r[1].strip() for r in rows}
    assert all(re.fullmatch(r"[\d.]+ / [\d.]+ / [\d.]+", v) for v in psnr.values())
    assert all(re.fullmatch(r" [\d.]+ / [\d.]+ ", r[4]) for r in rows)  # l = 0.9 / 0.95
    assert len(set(psnr.values())) > 1  # the variants trained
    from archhead_addon.train.loop import load_state

    assert load_state(tmp_path / "later" / "preset" / "train_state.pt")["step"] == 32 + 5


def test_step_times_stamps_a_run_and_prices_its_checkpoints(repo_root, tiny_subject, tmp_path):
    from training_subject import write_config

    config = write_config(tmp_path / "tiny.json", stage1_steps=12, stage2_steps=8)
    log = tmp_path / "events.jsonl.gz"
    out = _benchmark(
        repo_root, "step_times.py", "--log", log, "--config", config, "--",
        "--data", tiny_subject, "--out", tmp_path / "run", "--config", config,
    )  # fmt: skip
    assert out.startswith("20 of 20 steps on cpu (cpu)")
    rows = {line.split("|")[1].strip(): line for line in out.splitlines() if line[:4] == "| 1 "}
    rows |= {line.split("|")[1].strip(): line for line in out.splitlines() if line[:4] == "| 2 "}
    # 19 gaps between 20 steps, 4 of them across the checkpoints after steps 4, 8, 12, 16
    assert int(rows["1"].split("|")[2]) + int(rows["2"].split("|")[2]) == 15
    assert "(the mean over 4 checkpoints)" in out
    assert re.search(r"the whole run at these rates: [\d.]+ min \(.* in 5 checkpoints\)", out)
    again = _benchmark(repo_root, "step_times.py", "--log", log)  # the log alone
    assert again.splitlines()[:6] == out.splitlines()[:6]


def test_lpips_schedule_times_every_variant_of_both_stages(repo_root, tiny_subject, tmp_path):
    from training_subject import write_config

    config = write_config(tmp_path / "tiny.json", stage1_steps=2, stage2_steps=2)
    out = _benchmark(
        repo_root, "lpips_schedule.py", "--data", tiny_subject, "--config", config,
        "--steps", 1, "--threads", 1,
    )  # fmt: skip
    rows = [line.split("|")[1:3] for line in out.splitlines() if line.startswith(("| 1", "| 2"))]
    assert [s.strip() for s, _ in rows] == ["1"] * 3 + ["2"] * 3
    assert rows[0][1].strip() == "as configured"


def test_perceptual_precision_compares_float32_with_bfloat16(repo_root):
    out = _benchmark(repo_root, "perceptual_precision.py", "--size", 48, "--rounds", 1)
    rows = [line.split("|")[1].strip() for line in out.splitlines() if line.startswith("| ")]
    assert rows[1:] == ["float32", "bfloat16 autocast"]
    assert re.search(r"float32 / bfloat16: [\d.]+x", out)


def test_perceptual_fold_times_both_forms_and_finds_them_equal(repo_root):
    out = _benchmark(repo_root, "perceptual_fold.py", "--size", 48, "--rounds", 2)
    found = re.search(
        r"distance ([\d.]+) against ([\d.]+), image gradient max difference (\S+)", out
    )
    assert re.search(r"unfolded [\d.]+ ms, folded [\d.]+ ms, [\d.]+x", out)
    assert found and found[1] == found[2] and float(found[3]) < 1e-6


def test_gpu_check_answers_help_and_refuses_without_cuda(repo_root):
    import torch

    helped = subprocess.run(
        [sys.executable, "benchmarks/gpu_check.py", "--help"],
        cwd=repo_root,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert helped.returncode == 0 and "--minutes" in helped.stdout
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is here: gpu_check runs for real")
    done = subprocess.run(
        [sys.executable, "benchmarks/gpu_check.py", "--out", "unused.md"],
        cwd=repo_root,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2 and "no CUDA device" in done.stderr
    assert not (repo_root / "unused.md").exists()


def test_gpu_bundle_packs_the_check_for_a_gpu_machine(tiny_subject, tmp_path, repo_root):
    """scripts/gpu_bundle.py: JPEG frames, white outside the mask and close to the PNG inside
    it, the masks, regions and tracking as they were, gsplat and only the AlexNet ST-LPIPS
    weights."""
    import shutil

    import numpy as np
    from PIL import Image

    subject = tmp_path / tiny_subject.name  # with regions/, as the tracker writes them
    shutil.copytree(tiny_subject, subject)
    (subject / "regions").mkdir()
    for mask in (subject / "masks").glob("*.png"):
        inside = np.asarray(Image.open(mask).convert("L")) > 0
        Image.fromarray((inside * 255).astype(np.uint8)).save(subject / "regions" / mask.name)
    bundle = tmp_path / "bundle"
    command = [sys.executable, "scripts/gpu_bundle.py", "--data", str(subject)]
    command += ["--out", str(bundle)]
    done = subprocess.run(
        command,
        cwd=repo_root,
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    )
    psnr = float(re.search(r"JPEG frames ([\d.]+) dB", done.stdout).group(1))
    assert psnr > 35
    data = bundle / "data" / subject.name
    pngs = sorted((subject / "frames").glob("*.png"))
    assert [p.stem for p in pngs] == sorted(p.stem for p in (data / "frames").glob("*.jpg"))
    mask = np.asarray(Image.open(data / "masks" / pngs[0].name))
    assert np.array_equal(mask, np.asarray(Image.open(subject / "masks" / pngs[0].name)))
    for name in (p.name for p in pngs):
        region = np.asarray(Image.open(data / "regions" / name))
        assert np.array_equal(region, np.asarray(Image.open(subject / "regions" / name)))
    frame = np.asarray(Image.open(data / "frames" / f"{pngs[0].stem}.jpg")).astype(int)
    assert frame[mask == 0].mean() > 250  # white (the subject's own frames are black there)
    assert (data / "tracking.npz").read_bytes() == (subject / "tracking.npz").read_bytes()
    assert (bundle / "site" / "gsplat" / "__init__.py").is_file()
    weights = sorted(p.name for p in (bundle / "site" / "stlpips_pytorch").rglob("*.pth"))
    assert weights == ["alex_shift_tolerant.pth"]
    script = (bundle / "run.sh").read_text()
    assert f"--data $B/data/{subject.name}" in script and "--score" not in script
    refused = subprocess.run(
        command,
        cwd=repo_root,
        capture_output=True,
        text=True,
    )
    assert refused.returncode != 0 and "exists" in refused.stderr
