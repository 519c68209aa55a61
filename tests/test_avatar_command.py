"""`python -m archhead_addon avatar`: a real clip tracked and trained in one command, and
run again, each finished stage kept."""

import argparse
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from archhead_addon.track.real_subject import fetch_media
from archhead_addon.train.config import config_data


def avatar_args(out, **changes) -> argparse.Namespace:
    """The `avatar` command's arguments, as its parser gives them."""
    values = {"video": "clip.mp4", "flame": None, "frames": None, "preset": "cpu"}
    values.update(progress_json=False, frame_budget=900, minutes=0.0)
    return argparse.Namespace(out=out, **{**values, **changes})


def test_video_to_avatar_stopped_resumed_then_kept(tmp_path):
    """Ctrl-C to the command alone (as Blender's Cancel sends it) stops training at a
    checkpoint; the same command resumes it, and a third run keeps both stages. `--preset`
    takes a config file too: the demo preset's, 120 steps (110 after the first checkpoint: time
    for the signal to land before the run ends, on busy cores too)."""
    video = fetch_media() / "single_face.mp4"
    out = tmp_path / "me"
    preset = tmp_path / "short_demo.json"
    steps = {"stage1_steps": 80, "stage2_steps": 40, "checkpoint_every": 10}
    preset.write_text(json.dumps({**config_data("demo"), **steps}))
    command = [sys.executable, "-m", "archhead_addon", "avatar", str(video), "--out", str(out)]
    command += ["--preset", str(preset), "--frames", "12"]
    manifest = out / "run" / "checkpoint.json"
    first = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.monotonic() + 600
    while not manifest.is_file() and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.2)
    first.send_signal(signal.SIGINT)
    stderr = first.communicate(timeout=300)[1]
    assert first.returncode == 130, stderr[-2000:]
    stopped = json.loads(manifest.read_text())["step"]
    assert 0 < stopped < 120 and "train stopped" in stderr
    assert (out / "data" / "tracking.npz").is_file() and (out / "data" / "masks_person").is_dir()

    second = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert second.returncode == 0, second.stderr[-2000:]
    assert "track: done earlier, kept" in second.stderr and "resum" in second.stderr.lower()
    assert json.loads(manifest.read_text())["step"] == 120
    config = json.loads((out / "run" / "config.json").read_text())
    assert config["holdout"] == "interleaved" and config["mask"] == "head"
    assert "Load Avatar" in second.stderr and str(out / "run" / "avatar.npz") in second.stderr
    third = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert third.returncode == 0 and third.stderr.count("done earlier, kept") == 2


def test_a_stopped_run_resumes_and_a_bad_video_names_the_stage(tmp_path):
    from archhead_addon.video_avatar import stages_done, train_command

    args = avatar_args(tmp_path)

    assert stages_done(tmp_path) == {"tracked": False, "trained": False}
    assert "--resume" not in train_command(args)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "train_state.pt").write_bytes(b"")
    assert "--resume" in train_command(args) and "--config" not in train_command(args)
    bad = tmp_path / "not_a_video.mp4"
    bad.write_bytes(b"no video here")
    done = subprocess.run(
        [sys.executable, "-m", "archhead_addon", "avatar", str(bad), "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2 and "not_a_video.mp4" in done.stderr
    assert "track stopped" in done.stderr
    # A bad config file is refused before the tracking's minutes, naming the file and key.
    config = tmp_path / "mine.json"
    config.write_text(json.dumps({"stage1_steps": -1}))
    refused = subprocess.run(
        [sys.executable, "-m", "archhead_addon", "avatar", str(bad), "--out", str(tmp_path / "y")]
        + ["--preset", str(config)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert refused.returncode == 2 and "track stopped" not in refused.stderr
    assert "mine.json: key 'stage1_steps'" in refused.stderr and not (tmp_path / "y").exists()


def test_both_stages_wait_as_chosen_before_tracking(tmp_path, monkeypatch):
    """The command chooses how OpenMP threads wait while the cores are as other jobs left
    them, and both stages inherit it: training, choosing alone after the tracker, read the
    tracker's own load as other jobs' and let its threads sleep on quiet cores."""
    from archhead_addon import video_avatar

    args = avatar_args(tmp_path)

    for name in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT"):
        monkeypatch.delenv(name, raising=False)
    loads = iter([0.1] + [2.0] * 10)  # quiet at the start, then the tracker's load
    monkeypatch.setattr(os, "getloadavg", lambda: (next(loads),) * 3)
    seen = {}

    def stage(command):
        name = "train" if "archhead_addon.train" in command else "track"
        seen[name] = {k: os.environ.get(k) for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
        return 0

    monkeypatch.setattr(video_avatar, "_run_stage", stage)
    assert video_avatar.run_avatar(args) == 0
    assert seen["track"] == seen["train"]
    assert seen["train"]["GOMP_SPINCOUNT"] and seen["train"]["OMP_WAIT_POLICY"] is None


def test_training_gets_what_tracking_left_of_the_time_limit(tmp_path, monkeypatch, capsys):
    """`--minutes 30` with 10 minutes of tracking: training is given 20; with 29.5, none is
    left and the command stops before training (status 1), saying so; -1 is refused."""
    from archhead_addon import video_avatar

    args = avatar_args(tmp_path, minutes=30.0)

    tracking = {"minutes": 10.0}
    given = []

    def stage(command):
        if "archhead_addon.train" in command:
            given.append(float(command[command.index("--minutes") + 1]))
        else:
            args.started -= 60 * tracking["minutes"]  # as if tracking had taken that long
        return 0

    monkeypatch.setattr(video_avatar, "_run_stage", stage)
    assert video_avatar.run_avatar(args) == 0
    assert given == [pytest.approx(20.0, abs=0.05)]
    tracking["minutes"] = 29.5
    assert video_avatar.run_avatar(args) == 1 and len(given) == 1
    assert "leaves no time to train" in capsys.readouterr().err
    args.minutes = -1.0
    assert video_avatar.run_avatar(args) == 2
    assert "--minutes" in capsys.readouterr().err
