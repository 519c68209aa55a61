"""The training operator on tiny real runs of the backend: a run to the end loads its avatar
onto the head; a cancelled run stops on SIGINT with a saved checkpoint; the log stays."""

import importlib
import json
import time
from pathlib import Path

import bpy
import numpy as np
import pytest

from archhead_addon.avatar.checkpoint_format import read_checkpoint
from archhead_addon.sequences import read_sequence, write_canonical
from archhead_addon.synthetic.png import encode_png

pytestmark = pytest.mark.blender

TINY = {
    "lods_per_step": 2,
    "checkpoint_every": 1000,
    "avatar": {"s_max": 64, "s_min": 32, "levels": [64, 32], "feature_dim": 16},
}


@pytest.fixture(scope="module")
def setup(tmp_path_factory, demo_scene, addon):
    folder = tmp_path_factory.mktemp("train")
    head, seq = demo_scene(folder, frames=3)
    video = folder / "video"  # frames and tracking apart: the operator assembles the data
    video.mkdir()
    for t in range(len(seq)):
        (video / f"img_{t}.png").write_bytes(
            encode_png(np.full((32, 32, 3), 60 + 50 * t, np.uint8))
        )
    write_canonical(seq, folder / "track.npz")
    config = folder / "tiny.json"
    config.write_text(json.dumps(TINY))
    module = importlib.import_module("archhead_blender.training")
    return {
        "folder": folder,
        "head": head,
        "video": video,
        "config": config,
        "ops": module,
        "addon": addon,
    }


def test_training_operator_runs_and_loads_the_avatar(setup):
    out = setup["folder"] / "run"
    bpy.context.view_layer.objects.active = setup["head"]
    result = bpy.ops.archhead.train_avatar(
        frames_dir=str(setup["video"]),
        tracking=str(setup["folder"] / "track.npz"),
        out_dir=str(out),
        resolution=32,
        stage1_steps=2,
        stage2_steps=1,
        base_config=str(setup["config"]),
    )
    assert result == {"FINISHED"}
    ckpt = read_checkpoint(out / "avatar.npz")
    assert ckpt.config.s_max == 64 and ckpt.config.levels == (64, 32)
    avatar = bpy.data.objects[f"{setup['head'].name}_avatar"]
    assert bpy.path.abspath(avatar.archhead_avatar.checkpoint) == str(out / "avatar.npz")
    assert len(avatar.data.vertices) > 0
    log = (out / "train.log").read_text()
    assert "--progress-json" in log and '"event": "done"' in log and "[exit code 0]" in log
    request = json.loads((out / "train_request.json").read_text())
    assert request["stage1_steps"] == 2 and request["avatar"]["s_max"] == 64
    staged = out / "data"
    assert (staged / "frames").resolve() == setup["video"].resolve()
    assert len(read_sequence(staged / "tracking.npz")) == 3
    assert setup["ops"].current_run() is None


def test_cancel_stops_cleanly_with_a_checkpoint(setup):
    ops = setup["ops"]
    out = setup["folder"] / "cancelled"
    settings = {**TINY, "resolution": 32, "stage1_steps": 200, "stage2_steps": 0}
    run = ops.start_training(
        bpy.context,
        setup["video"],
        setup["folder"] / "track.npz",
        out,
        settings,
        head_name=setup["head"].name,
    )
    assert ops.current_run() is run
    deadline = time.monotonic() + 120
    while run.step < 1:  # what the modal operator's timer does: poll, never wait
        assert not run.update(), (out / "train.log").read_text()[-2000:]
        assert time.monotonic() < deadline
        time.sleep(0.2)
    assert 0 < run.fraction < 1 and "ETA" in run.summary() and "loss" in run.loss_text()
    run.backend.cancel()
    while not run.update():
        assert time.monotonic() < deadline
        time.sleep(0.2)
    kind, message = ops.finish_training(bpy.context, run)
    assert kind == "INFO" and message.startswith("Stopped"), message
    assert run.backend.returncode == 130  # the backend's status for a run stopped by SIGINT
    assert 1 <= run.step < 200
    assert '"event": "interrupted"' in (out / "train.log").read_text()
    assert read_checkpoint(out / "avatar.npz").config.s_max == 64


def tracked_folder(setup) -> Path:
    """What Track Video writes: frames/ beside tracking.npz."""
    import shutil

    data = setup["folder"] / "tracked"
    if not data.exists():
        shutil.copytree(setup["video"], data / "frames")
        shutil.copy(setup["folder"] / "track.npz", data / "tracking.npz")
    return data


def test_train_dialog_names_empty_fields_and_keeps_what_was_typed(setup):
    state = importlib.import_module("archhead_blender.state").STATE
    bpy.context.view_layer.objects.active = setup["head"]
    with pytest.raises(RuntimeError, match="Frames: choose the folder"):
        bpy.ops.archhead.train_avatar(out_dir=str(setup["folder"] / "x"))
    data = tracked_folder(setup)
    with pytest.raises(RuntimeError, match="Output: choose a folder"):
        bpy.ops.archhead.train_avatar(frames_dir=str(data / "frames"), preset="demo")
    assert not (setup["folder"] / "x").exists()
    kept = state.dialog_fields["train_avatar"]
    assert kept["frames_dir"] == str(data / "frames") and kept["preset"] == "demo"
    assert "out_dir" not in kept and "tracking" not in kept  # what the user typed, only


def test_a_tracked_folder_trains_into_a_new_output_folder_with_a_preset(setup):
    """The tracking is found beside frames/, the output folder is created, and the preset's
    values train where the fields were left alone; the time limit reaches the backend."""
    from archhead_addon.train.config import config_data

    data = tracked_folder(setup)
    out = setup["folder"] / "new" / "run"
    bpy.context.view_layer.objects.active = setup["head"]
    result = bpy.ops.archhead.train_avatar(
        frames_dir=str(data / "frames"),
        out_dir=str(out),
        preset="demo",
        resolution=32,
        stage1_steps=2,
        stage2_steps=1,
        minutes=5.0,
    )
    assert result == {"FINISHED"}
    assert json.loads((out / "config.json").read_text())["minutes"] == 5.0
    assert "within 5 min" in (out / "train.log").read_text()
    request = json.loads((out / "train_request.json").read_text())
    demo = config_data("demo")
    assert request == {**demo, "resolution": 32, "stage1_steps": 2, "stage2_steps": 1}
    assert read_checkpoint(out / "avatar.npz").config.s_max == demo["avatar"]["s_max"]
    assert not (out / "data").exists()  # the tracked folder was used as it is


def test_train_dialog_fills_in_the_head_tracked_by_track_video(setup):
    module = importlib.import_module(f"{setup['addon'].__name__}.operators.train_operator")
    data = tracked_folder(setup)
    head = setup["head"]
    before = head.get("archhead_sequence")
    head["archhead_sequence"] = str(data / "tracking.npz")
    try:
        assert module._tracked_folder(head) == data
    finally:
        head["archhead_sequence"] = before
    assert module._tracked_folder(head) is None  # imported from elsewhere: nothing to guess


def test_avatar_from_video_on_a_tracked_folder_imports_trains_loads_and_goes_on(setup, monkeypatch):
    """Avatar from Video (issue 31) in `blender -b` on a folder whose tracking is done (as a
    stopped run leaves it): no tracking, the head imported and named after the folder, the
    preset trained with the interleaved holdout, the avatar loaded; again on the finished
    folder: the same head, the avatar loaded again, no training."""
    import shutil

    module = importlib.import_module("archhead_blender.video_avatar")
    real = module.training_settings

    def tiny(overrides, preset):  # the preset's settings at a test's size
        return {**real(overrides, preset), "resolution": 32, "stage1_steps": 2, "stage2_steps": 1}

    monkeypatch.setattr(module, "training_settings", tiny)
    out = setup["folder"] / "from_video" / "subject"
    shutil.copytree(tracked_folder(setup), out / "data")
    assert module.folder_state(str(out)) == "Tracked here: trains"
    result = bpy.ops.archhead.avatar_from_video(out_dir=str(out), preset="demo")
    assert result == {"FINISHED"}
    head = bpy.data.objects["subject"]
    avatar = bpy.data.objects["subject_avatar"]
    assert avatar.archhead_avatar.head == head and len(avatar.data.vertices) > 0
    request = json.loads((out / "run" / "train_request.json").read_text())
    assert request["holdout"] == "interleaved" and request["stage1_steps"] == 2
    assert module.folder_state(str(out)) == "Trained here: loads the avatar"
    assert module.current_video_run() is None and setup["ops"].current_run() is None
    log = (out / "run" / "train.log").read_text()
    objects = sorted(bpy.data.objects.keys())
    assert bpy.ops.archhead.avatar_from_video(out_dir=str(out), preset="demo") == {"FINISHED"}
    assert sorted(bpy.data.objects.keys()) == objects  # the head reused, no second one
    assert (out / "run" / "train.log").read_text() == log  # nothing trained again
    with pytest.raises(RuntimeError, match="Video: choose the video"):
        bpy.ops.archhead.avatar_from_video(out_dir=str(setup["folder"] / "empty"))
    # a time limit that tracking has spent (under a minute left) stops before training
    spent = setup["folder"] / "from_video" / "spent"
    shutil.copytree(tracked_folder(setup), spent / "data")
    with pytest.raises(RuntimeError, match="leaves no time to train"):
        bpy.ops.archhead.avatar_from_video(out_dir=str(spent), preset="demo", minutes=0.5)
    assert not (spent / "run").exists() and module.current_video_run() is None
