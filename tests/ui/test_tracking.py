"""Track Video from the panel on the real Pexels clip's first frames
(tests/ui/blender/track_workflow.py): cancel half way, then a run imported as a head."""

import os
import shutil

import pytest

pytestmark = pytest.mark.ui

FRAMES = 8  # about a minute on the 2-core machine


def test_track_video_progress_cancel_and_import(blender_session, ui_data):
    from ui_session import OUT

    from archhead_addon.track.real_subject import REAL_VIDEO, fetch_media

    source = fetch_media() / REAL_VIDEO  # `make setup` fetched it
    video = ui_data["folder"] / REAL_VIDEO  # inside the checkout, which the env binds
    if not video.is_file():
        shutil.copyfile(source, video)
    out = OUT / "tracking"
    if out.exists():
        shutil.rmtree(out)
    result = blender_session.ui(
        "track_workflow.py", out, str(video), str(out / "runs"), str(FRAMES)
    )
    assert result["data"]["frames"][1] - result["data"]["frames"][0] + 1 == FRAMES
    for pid in result["data"]["backend_pids"]:
        assert not os.path.exists(f"/proc/{pid}")
    assert (out / "runs" / "clip" / "tracking.npz").is_file()
    assert not (out / "runs" / "cancelled").exists()
