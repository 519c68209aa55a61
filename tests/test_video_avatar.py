"""`python -m archhead_addon avatar`: a real clip tracked and trained in one command, and
run again, each finished stage kept."""

import json
import subprocess
import sys

import pytest

from archhead_addon.track.real_subject import fetch_media


@pytest.mark.slow
def test_video_to_avatar_then_again_keeps_what_is_done(tmp_path, repo_root):
    video = fetch_media() / "single_face.mp4"
    out = tmp_path / "me"
    command = [sys.executable, "-m", "archhead_addon", "avatar", str(video), "--out", str(out)]
    command += ["--preset", "demo", "--frames", "12"]
    first = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert first.returncode == 0, first.stderr[-2000:]
    assert (out / "data" / "tracking.npz").is_file() and (out / "data" / "masks_person").is_dir()
    manifest = json.loads((out / "run" / "checkpoint.json").read_text())
    assert manifest["step"] == manifest["total_steps"] == 600
    config = json.loads((out / "run" / "config.json").read_text())
    assert config["holdout"] == "interleaved" and config["mask"] == "head"
    assert "Load Avatar" in first.stderr and str(out / "run" / "avatar.npz") in first.stderr
    again = subprocess.run(command, capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert again.returncode == 0
    assert again.stderr.count("done earlier, kept") == 2


def test_a_stopped_run_resumes_and_a_bad_video_names_the_stage(tmp_path):
    from archhead_addon.video_avatar import stages_done, train_command

    class Args:
        out, video, flame, frames, preset, progress_json = tmp_path, None, None, None, "cpu", False

    assert stages_done(tmp_path) == {"tracked": False, "trained": False}
    assert "--resume" not in train_command(Args)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "train_state.pt").write_bytes(b"")
    assert "--resume" in train_command(Args) and "--config" not in train_command(Args)
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
