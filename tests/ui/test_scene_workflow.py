"""File > Import, the panel, Load Avatar, undo / redo, modal Decode with a cancel, LOD by hand
and by the camera-distance driver during playback, save; then the saved file reopened in a
new window (tests/ui/blender/scene_workflow.py, reopen.py)."""

import pytest

pytestmark = pytest.mark.ui


def test_import_load_decode_lod_save(saved_scene):
    result, blend = saved_scene
    data = result["data"]
    assert data["gaussians_by_lod"]["0.0"] > 5 * data["gaussians_by_lod"]["1.0"]
    assert 0 < data["decode"]["done_at_cancel"] < data["decode"]["total"]
    assert blend.is_file()


def test_reopen_attaches_handlers_and_survives_disable_enable(blender_session, saved_scene):
    from ui_session import OUT

    _, blend = saved_scene
    result = blender_session.ui("reopen.py", OUT / "reopen", "talking_head", blend=str(blend))
    assert "on_frame_change" in result["data"]["handlers"]["frame_change_post"]
