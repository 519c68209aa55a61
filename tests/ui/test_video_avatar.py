"""Avatar from Video from the panel (issue 31) on the real Pexels clip's first frames with the
demo preset (tests/ui/blender/video_avatar.py): cancelled during training, then, in a new
Blender, run again on the same Output: the tracking is kept, the training resumed to the end
and the avatar loaded onto the imported head."""

import json
import os
import re
import shutil

import pytest

pytestmark = pytest.mark.ui

FRAMES = 8  # as test_tracking.py: about a minute of tracking on the 2-core machine


def test_avatar_from_video_cancel_then_resume_to_the_end(blender_session, ui_data):
    from ui_session import OUT

    from archhead_addon.track.real_subject import REAL_VIDEO, fetch_media

    video = ui_data["folder"] / REAL_VIDEO  # inside the checkout, which the env binds
    if not video.is_file():
        shutil.copyfile(fetch_media() / REAL_VIDEO, video)
    out = OUT / "video_avatar"
    if out.exists():
        shutil.rmtree(out)
    folder = out / "clip"  # what the artist picks as Output: it holds everything
    args = (str(video), str(folder), str(FRAMES))
    first = blender_session.ui("video_avatar.py", out / "cancel", *args, "cancel", quiet=90)
    assert first["data"]["folder_state"] == "Tracked here: resumes training"
    run = folder / "run"
    stopped = json.loads((run / "checkpoint.json").read_text())["step"]
    assert 0 < stopped < 600

    second = blender_session.ui("video_avatar.py", out / "resume", *args, "resume", quiet=60)
    for pid in first["data"]["backend_pids"] + second["data"]["backend_pids"]:
        assert not os.path.exists(f"/proc/{pid}")
    assert second["data"]["gaussians"] > 0
    assert second["data"]["first_step"] >= stopped
    # everything is in the chosen folder: the tracking (tracked once), the run (resumed once,
    # from where it stopped, and finished)
    assert (folder / "data" / "tracking.npz").is_file()
    assert (folder / "data.track.log").read_text().count("$ ") == 1
    log = (run / "train.log").read_text()
    starts = [int(s) for s in re.findall(r'"event": "start", "step": (\d+)', log)]
    assert starts == [0, stopped], starts
    assert '"event": "done"' in log
    manifest = json.loads((run / "checkpoint.json").read_text())
    assert manifest["step"] == manifest["total_steps"]
    assert (run / "avatar.npz").is_file()
