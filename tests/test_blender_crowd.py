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

    # a deleted avatar's session retires (a redo may bring its object back); its share of
    # the decoder goes with the oldest retired ones, or a file load
    prune = _module("avatar_session").prune_sessions
    copy_name = copy[2].name
    bpy.data.objects.remove(copy[2])
    prune(force=True)
    assert len(state.decoders) == 1 and set(state.retired) == {copy_name}
    bpy.data.objects.remove(original[2])
    prune(force=True)
    assert not state.sessions and len(state.retired) == 2 and len(state.decoders) == 1
    _module("state").reset()
    assert not state.decoders and not state.retired


def test_all_avatars_frames_stay_within_the_preferences_total(
    tmp_path, demo_scene, tiny_checkpoint
):
    """Each avatar's Memory cache adds to its decoder's, but all of them together stay within
    the add-on preferences' total (a crowd's frames would pass the machine's memory)."""
    session = _module("avatar_session").session
    prefs = _module("preferences").get_preferences(bpy.context)
    head, _ = demo_scene(tmp_path)
    original = _avatar_set(head, tiny_checkpoint)
    copy = _duplicate(list(original), linked=False)
    bpy.context.scene.frame_set(1)
    memory = session(original[2]).shared.memory
    assert session(copy[2]).shared.memory is memory
    each = original[2].archhead_avatar.memory_mb << 20
    total = prefs.memory_total_mb
    try:
        prefs.memory_total_mb = 64  # below the two avatars' 2 x 1024 MB: scaled down to it
        assert memory.max_bytes == 64 << 20 < 2 * each
        prefs.memory_total_mb = 4 * (each >> 20)  # above their sum: each keeps its own
        assert memory.max_bytes == 2 * each
    finally:
        prefs.memory_total_mb = total


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


def test_a_scene_refresh_decodes_each_frame_once_and_a_failing_avatar_spares_the_others(
    tmp_path, demo_scene, tiny_checkpoint
):
    """The handler finds every avatar's frame, decodes the missing ones together (two heads
    that play the same codes share one decode) and then writes them; an avatar whose decode
    fails keeps its points and says why, and the others still show the new frame."""
    import shutil

    session, state = _module("avatar_session").session, _module("state").STATE
    head, _ = demo_scene(tmp_path)
    original = _avatar_set(head, tiny_checkpoint)
    copy = _duplicate(list(original), linked=False)
    copy[1].location.x += 0.4
    other = _avatar_set(*_duplicate([head], linked=False), shutil.copy(tiny_checkpoint, tmp_path))
    scene = bpy.context.scene
    scene.frame_set(1)
    shared, failing = session(original[2]).shared, session(other[2]).shared
    assert session(copy[2]).shared is shared and failing is not shared
    decode, calls = shared.decode, []
    shared.decode = lambda request, *posed: calls.append(request) or decode(request, *posed)
    failing.decode = lambda *_: (_ for _ in ()).throw(ValueError("a broken frame"))
    before = _points(other[2])
    try:
        scene.frame_set(3)
    finally:
        del shared.decode, failing.decode
    assert len(calls) == 1, "two heads playing the same codes decoded their frame twice"
    shown = {session(o[2]).shown[0] for o in (original, copy)}
    assert shown == {shared.key(calls[0].codes, calls[0].lod)}
    assert "a broken frame" in state.errors[other[2].session_uid]
    assert original[2].session_uid not in state.errors and copy[2].session_uid not in state.errors
    np.testing.assert_array_equal(_points(other[2]), before)
    scene.frame_set(4)  # decodes again: the error is gone
    assert other[2].session_uid not in state.errors


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


def test_the_budget_raises_every_level_by_the_least_common_amount():
    crowd = _module("crowd")
    sizes = [(60_000, 256, 64)] * 3
    wanted = [0.0, 0.3, 0.9]
    assert crowd.budget_bias(wanted, sizes, 0) == 0.0  # no budget
    assert crowd.budget_bias(wanted, sizes, 10**9) == 0.0  # fits as it is
    assert crowd.budget_bias(wanted, sizes, 100) == 1.0  # not even LOD 1 everywhere fits

    def total(b):
        pairs = zip(wanted, sizes, strict=True)
        return sum(crowd.gaussians_at(min(w + b, 1), *s) for w, s in pairs)

    budget = 50_000
    b = crowd.budget_bias(wanted, sizes, budget)
    assert 0 < b < 1 and total(b) <= budget < total(b - 1e-3)


def test_crowd_operators_load_drive_and_budget_every_selected_head(
    tmp_path, demo_scene, tiny_checkpoint
):
    head, _ = demo_scene(tmp_path)
    bpy.context.view_layer.objects.active = head
    second = _duplicate([head, head.parent], linked=False)  # a second head, no avatar yet
    second[1].location.x += 0.4
    for obj in (head, second[0]):
        obj.select_set(True)
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.archhead.load_avatar(filepath=str(tiny_checkpoint)) == {"FINISHED"}
    avatar_of = _module("avatar_objects").avatar_of
    avatars = [avatar_of(head), avatar_of(second[0])]
    assert all(a is not None for a in avatars)
    for obj in avatars:
        obj.select_set(True)

    scene = bpy.context.scene
    assert bpy.ops.archhead.drive_lod(near=0.1, far=20.0) == {"FINISHED"}
    scene.frame_set(1)

    def levels():
        depsgraph = bpy.context.evaluated_depsgraph_get()
        return [a.evaluated_get(depsgraph).archhead_avatar.lod for a in avatars]

    base = levels()
    assert all(0 < v < 1 for v in base)
    scene.archhead_crowd.lod_bias = 0.2  # one slider for every driven avatar
    assert levels() == pytest.approx([v + 0.2 for v in base], abs=1e-5)
    scene.archhead_crowd.lod_bias = 0.0

    # screen size: S falls as 1 / (distance through the lens), S_max at near
    near, far = 0.2, 0.8
    assert bpy.ops.archhead.drive_lod(near=near, far=far, mode="SCREEN") == {"FINISHED"}
    camera = scene.camera
    depsgraph = bpy.context.evaluated_depsgraph_get()

    def distance(avatar):
        rig = avatar.archhead_avatar.head.parent.evaluated_get(depsgraph)
        root = rig.matrix_world @ rig.pose.bones["global"].head
        return (camera.matrix_world.translation - root).length

    lens = camera.data.lens
    for zoom in (1.0, 2.0):  # zooming in (a longer lens) gives the detail of a nearer camera
        camera.data.lens = zoom * lens
        want = [
            min(max((1 - near * zoom * lens / (distance(a) * 50)) / (1 - near / far), 0), 1)
            for a in avatars
        ]
        assert levels() == pytest.approx(want, abs=1e-4)
        assert 0 < min(want) and max(want) < 1  # between near and far: no clamp hides it
    camera.data.lens = lens

    # the scene's Gaussian budget: the avatars show no more than it, together
    scene.archhead_crowd.lod_bias = 0.0
    scene.frame_set(2)
    free = sum(len(a.data.vertices) for a in avatars)
    scene.archhead_crowd.gaussian_budget = free // 2
    scene.frame_set(3)
    shown = sum(len(a.data.vertices) for a in avatars)
    assert shown <= free // 2
    assert shown > free // 8  # raised no further than needed
    scene.archhead_crowd.gaussian_budget = 0


def test_an_avatar_that_comes_back_keeps_its_decoded_frames(tmp_path, demo_scene, tiny_checkpoint):
    """What a redo of Load Avatar does (the UI suite presses the keys): the object goes, a new
    one of its name and settings comes; it takes the retired session, decoded frames and all."""
    session = _module("avatar_session").session
    head, _ = demo_scene(tmp_path)
    _, _, obj = _avatar_set(head, tiny_checkpoint)
    _module("decoding").decode_frames(bpy.context, obj, [2, 3])
    decoded = dict(session(obj).decoded)
    bpy.data.objects.remove(obj)
    bpy.context.view_layer.update()
    _, _, back = _avatar_set(head, tiny_checkpoint)
    assert session(back).decoded.keys() == decoded.keys() == {2, 3}
    assert all(session(back).decoded[f].key == decoded[f].key for f in decoded)


def test_the_texel_count_fit_is_exact_at_both_ends_and_close_between(
    tmp_path, demo_scene, tiny_checkpoint
):
    crowd, session = _module("crowd"), _module("avatar_session").session
    head, _ = demo_scene(tmp_path)
    _, _, obj = _avatar_set(head, tiny_checkpoint)
    avatar = session(obj)
    cfg, raster = avatar.runtime.config, avatar.runtime.raster
    n_max, n_min = avatar.shared.texels_at_ends()
    for lod in (0.0, 0.3, 0.5, 0.8, 1.0):
        size = avatar.runtime.resolution(lod)
        true = len(raster.table(size).texel)
        fit = crowd.gaussians_at(lod, n_max, cfg.s_max, cfg.s_min, n_min)
        assert fit == pytest.approx(true, rel=0.03 if 0 < lod < 1 else 1e-9)


def test_a_cached_frame_shown_again_reuses_its_codes_and_points(
    tmp_path, demo_scene, tiny_checkpoint
):
    """Playback of decoded frames: the handler finds each frame's codes by the rig's raw
    pose and keys and writes the points kept with the cache entry, and what it writes is
    what the frame's Gaussians give; a pose edited by hand still reaches the codes."""
    session = _module("avatar_session").session
    scene_state = _module("scene_state")
    point_instances = _module("point_instances")
    from archhead_addon.avatar.point_attributes import point_attributes

    head, _ = demo_scene(tmp_path)
    _, rig, obj = _avatar_set(head, tiny_checkpoint)
    scene = bpy.context.scene
    _module("decoding").decode_frames(bpy.context, obj, [2, 3])
    avatar = session(obj)
    convert = scene_state.codes_from_rig
    calls = []
    scene_state.codes_from_rig = lambda *a: calls.append(1) or convert(*a)
    try:
        for f in (2, 3, 2):
            scene.frame_set(f)
        assert not calls, "a decoded frame's pose was converted to codes again"
        depsgraph = bpy.context.evaluated_depsgraph_get()
        key, splat = _module("handlers").frame_to_show(obj, scene, depsgraph)
        assert key == avatar.decoded[2].key
        kept = avatar.shared.points(key, splat)
        assert kept is avatar.shared.points(key, splat)  # the entry's, not made again
        written = point_instances.read_points(obj)
        fresh = point_attributes(splat, None, avatar.runtime.config.colour_space)
        for name, array in fresh.items():
            np.testing.assert_array_equal(written[name], array.reshape(written[name].shape))

        # the joints' bones read in one call are the bones' own matrices
        bones = rig.evaluated_get(depsgraph).pose.bones
        expected = np.array([np.array(bones[n].matrix_basis) for n in scene_state.JOINT_NAMES])
        np.testing.assert_array_equal(
            scene_state.joint_basis(rig.evaluated_get(depsgraph)), expected
        )

        # a hand-posed jaw is a new raw pose: converted, and a new frame shown
        rig.pose.bones["jaw"].rotation_mode = "XYZ"
        rig.pose.bones["jaw"].rotation_euler.x += 0.2
        bpy.context.view_layer.update()
        assert calls
        assert avatar.shown[0] != key
    finally:
        scene_state.codes_from_rig = convert
