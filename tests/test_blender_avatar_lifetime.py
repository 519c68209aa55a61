"""Avatar runtimes and decoded frames live as long as the objects that own them: deleting an
avatar (and purging its orphans) frees them, so a session that imports, loads, scrubs and
deletes again and again holds its memory flat (bpy 5.0.1)."""

import importlib
import os
import sys

import bpy
import pytest

from archhead_addon.heap import release_free_memory, resident_mb

pytestmark = pytest.mark.blender

CYCLES = int(os.environ.get("ARCHHEAD_LIFETIME_CYCLES", 15))
FRAMES = 6  # frames scrubbed per cycle: each decodes (LOD 0.25, about 40k Gaussians)
LIMIT_MB = 50.0


def rss_mb() -> float:
    """Resident memory of this process now (not the peak that `resource` reports), once the
    allocators have returned their free pages: what the process holds, not where the
    allocator's holes happen to lie at that moment."""
    release_free_memory()
    return resident_mb()


def _state():
    return importlib.import_module("archhead_blender.state").STATE


def load_avatar(head, checkpoint):
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.archhead.load_avatar(filepath=str(checkpoint)) == {"FINISHED"}
    return bpy.data.objects[f"{head.name}_avatar"]


def cycle(sequence, checkpoint) -> None:
    """Import the head, load its avatar, scrub, delete everything the cycle made, purge."""
    before = set(bpy.data.objects.keys())
    assert bpy.ops.archhead.import_sequence(filepath=str(sequence)) == {"FINISHED"}
    head = next(o for o in bpy.data.objects if o.name not in before and "archhead_model_id" in o)
    obj = load_avatar(head, checkpoint)
    obj.archhead_avatar.lod = 0.25
    scene = bpy.context.scene
    for frame in range(1, FRAMES + 1):
        scene.frame_set(frame)
    assert len(_state().sessions) == 1
    for name in set(bpy.data.objects.keys()) - before:
        bpy.data.objects.remove(bpy.data.objects[name])
    bpy.data.orphans_purge(do_local_ids=True, do_linked_ids=True, do_recursive=True)
    bpy.context.view_layer.update()  # the depsgraph update the interface runs after a delete


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads /proc (Linux)")
def test_deleted_avatars_free_their_memory(tmp_path, demo_scene, tiny_checkpoint):
    demo_scene(tmp_path, frames=FRAMES)  # writes tmp_path/demo.npz, imported again below
    for name in list(bpy.data.objects.keys()):
        bpy.data.objects.remove(bpy.data.objects[name])
    sequence = tmp_path / "demo.npz"
    bpy.context.scene.frame_end = FRAMES

    cycle(sequence, tiny_checkpoint)  # warm-up: models, kernel tables and allocator pools
    start = rss_mb()
    for _ in range(CYCLES):
        cycle(sequence, tiny_checkpoint)
        assert not _state().sessions, "a deleted avatar's session outlived it"
    growth = rss_mb() - start
    print(f"{CYCLES} delete cycles: RSS {start:.0f} -> {start + growth:.0f} MB "
          f"(growth {growth:+.1f} MB)", file=sys.stderr)  # fmt: skip
    assert growth < LIMIT_MB


def test_unlinked_avatars_go_with_the_orphan_purge_and_every_file_load(
    tmp_path, demo_scene, tiny_checkpoint
):
    """An object unlinked from the scene still exists (undo can bring it back): its session
    stays until the purge removes the object. A file load forgets every session."""
    head, _ = demo_scene(tmp_path)
    obj = load_avatar(head, tiny_checkpoint)
    uid = obj.session_uid
    for collection in obj.users_collection:
        collection.objects.unlink(obj)
    bpy.context.view_layer.update()
    assert uid in _state().sessions
    bpy.data.orphans_purge(do_local_ids=True, do_linked_ids=True, do_recursive=True)
    bpy.context.view_layer.update()
    assert uid not in _state().sessions

    load_avatar(head, tiny_checkpoint)
    assert _state().sessions
    bpy.ops.wm.read_homefile(use_empty=True)
    assert not _state().sessions
