"""Track Video from Blender: the backend tracks a real clip and the head is imported; a file
that is not a video fails with the backend's message and leaves no folder."""

import bpy
import numpy as np
import pytest

from archhead_addon.sequences import read_sequence
from archhead_addon.track.real_subject import fetch_media
from archhead_blender.avatar_objects import head_of
from archhead_blender.tracking import current_tracking

pytestmark = pytest.mark.blender


def test_track_video_imports_the_tracked_head(addon, tmp_path):
    out = tmp_path / "tracked"
    before = {o.name for o in bpy.data.objects}
    result = bpy.ops.archhead.track_video(
        video=str(fetch_media() / "single_face.mp4"),
        out_dir=str(out),
        frames=10,
        frame_budget=5,
        size=128,
        static_offset=True,
    )
    assert result == {"FINISHED"}
    assert (out / "tracking.npz").is_file() and current_tracking() is None
    new = [bpy.data.objects[n] for n in {o.name for o in bpy.data.objects} - before]
    heads = {head_of(o) for o in new} - {None}
    assert [h.name for h in heads] == ["tracked"]
    head = next(iter(heads))
    # one frame in 2 of the first 10 (Most frames), keyed at the video's own times
    assert head.get("archhead_frames") == 5
    assert read_sequence(out / "tracking.npz").frame_ids.tolist() == [0, 2, 4, 6, 8]
    # the tracking's static offset travels with the head, for the avatar loaded onto it
    offset = np.asarray(head["archhead_identity_offset"]).reshape(-1, 3)
    assert offset.shape == (len(head.data.vertices), 3) and np.abs(offset).max() > 0


def test_track_video_reports_a_bad_file(addon, tmp_path):
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video\n")
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="notes.mp4"):
        bpy.ops.archhead.track_video(video=str(bad), out_dir=str(out))
    assert not out.exists() and current_tracking() is None
