"""Many avatars in one scene (bpy 5.0.1): avatars of one checkpoint share one decoder, Decode
Frames visits each frame once for all of them, a frame decoded ahead serves every camera's
culling without a new decode, and duplicated heads (Shift+D, Alt+D) are independent avatars."""

import importlib

import bpy
import numpy as np
import pytest

pytestmark = pytest.mark.blender


def _module(name):
    return importlib.import_module(f"archhead_blender.{name}")


def _duplicate(objects, linked: bool):
    """Shift+D (or Alt+D) of `objects`; the copies in the same order (Blender names each
    copy after its original: NAME.001)."""
    bpy.ops.object.select_all(action="DESELECT")
    for obj in objects:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = objects[0]
    assert bpy.ops.object.duplicate(linked=linked) == {"FINISHED"}
    copies = list(bpy.context.selected_objects)
    return [next(c for c in copies if c.name.rsplit(".", 1)[0] == o.name) for o in objects]


def _avatar_set(head, checkpoint):
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.archhead.load_avatar(filepath=str(checkpoint)) == {"FINISHED"}
    return head, head.parent, bpy.data.objects[f"{head.name}_avatar"]


def _points(obj) -> np.ndarray:
    """The avatar's point positions in world space."""
    mesh = obj.data
    out = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", out)
    world = np.array(obj.matrix_world)
    return out.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]


def test_copies_share_one_decoder_and_decode_in_one_pass(tmp_path, demo_scene, tiny_checkpoint):
    session, state = _module("avatar_session").session, _module("state").STATE
    head, _ = demo_scene(tmp_path)
    original = _avatar_set(head, tiny_checkpoint)
    copy = _duplicate(list(original), linked=False)
    copy[1].location.x += 0.4  # the copy's rig: its head stands beside the first
    scene = bpy.context.scene
    scene.frame_set(1)
    first, second = session(original[2]), session(copy[2])
    assert first is not second
    assert first.runtime is second.runtime and first.shared is second.shared
    assert len(state.decoders) == 1
    assert first.shared.memory.max_bytes == 2 * (original[2].archhead_avatar.memory_mb << 20)

    # Shift+D names its own head: the panel and the decode act on the copy, not the original
    head_of = _module("avatar_objects").head_of
    assert head_of(copy[1]) is copy[0] and head_of(copy[2]) is copy[0]
    assert copy[2].archhead_avatar.head is copy[0]
    assert not np.allclose(_points(copy[2]).mean(0), _points(original[2]).mean(0))

    # one pass over the frames for both avatars, each keeping its own decoded frames
    frames = [2, 3, 4]
    visited = _module("decoding").decode_frames(bpy.context, [original[2], copy[2]], frames)
    assert visited == len(frames)
    assert sorted(first.decoded) == sorted(second.decoded) == frames
    # the copy plays the same animation (its rig moved, not its codes): its frames are the
    # first's, decoded once into the shared cache
    assert all(first.decoded[f].key == second.decoded[f].key for f in frames)

    # deleting one keeps the shared decoder; deleting both frees it
    bpy.data.objects.remove(copy[2])
    bpy.context.view_layer.update()
    _module("avatar_session").prune_sessions(force=True)
    assert len(state.decoders) == 1
    assert first.shared.memory.max_bytes == original[2].archhead_avatar.memory_mb << 20
    bpy.data.objects.remove(original[2])
    _module("avatar_session").prune_sessions(force=True)
    assert not state.decoders


def test_a_frame_decoded_ahead_serves_culling_without_a_new_decode(
    tmp_path, demo_scene, tiny_checkpoint
):
    session = _module("avatar_session").session
    frame_to_show = _module("handlers").frame_to_show
    head, _ = demo_scene(tmp_path)
    _, _, obj = _avatar_set(head, tiny_checkpoint)
    scene = bpy.context.scene
    _module("decoding").decode_frames(bpy.context, obj, [2])
    avatar = session(obj)
    scene.frame_set(2)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    cached = len(avatar.shared.memory)
    decode = avatar.runtime.decode
    calls = []
    avatar.runtime.decode = lambda *a, **k: calls.append(1) or decode(*a, **k)
    try:
        _, whole = frame_to_show(obj, scene, depsgraph, culled=False)
        _, culled = frame_to_show(obj, scene, depsgraph, culled=True)
    finally:
        del avatar.runtime.decode
    assert not calls, "a frame decoded ahead was decoded again for the camera"
    assert len(avatar.shared.memory) == cached
    assert 0 < len(culled) <= len(whole)
    # the culled frame is a subset of the whole one: the camera sees every kept Gaussian
    kept = {tuple(p) for p in np.round(culled.means, 6)}
    assert kept <= {tuple(p) for p in np.round(whole.means, 6)}

    # a head wholly behind the camera: an empty cloud, not an error
    rig = head.parent
    camera = scene.camera
    behind = np.array(camera.matrix_world)[:3, 2] * 5.0  # Blender cameras look down -Z
    rig.location = (np.array(camera.matrix_world.translation) + behind).tolist()
    bpy.context.view_layer.update()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    _, gone = frame_to_show(obj, scene, depsgraph, culled=True)
    assert len(gone) == 0


def test_a_linked_duplicate_gets_points_of_its_own(tmp_path, demo_scene, tiny_checkpoint):
    head, _ = demo_scene(tmp_path)
    original = _avatar_set(head, tiny_checkpoint)
    copy = _duplicate(list(original), linked=True)
    # Alt+D links the copy to the original's point mesh; the first refresh gives it its own
    original[2].archhead_avatar.lod, copy[2].archhead_avatar.lod = 0.0, 1.0
    scene = bpy.context.scene
    scene.frame_set(1)
    scene.frame_set(2)
    assert copy[2].data is not original[2].data
    assert copy[2].data.users == 1 and original[2].data.users == 1
    # each shows its own level of detail, not whichever wrote last
    assert len(copy[2].data.vertices) < len(original[2].data.vertices)
