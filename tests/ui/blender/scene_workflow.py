"""An artist's first session: File > Import through the file browser, the panel, Load Avatar
(a failed one first: the scene stays as it was), undo and redo of both, a failed Replace
Checkpoint, a modal Decode cancelled half way, Ctrl+Z / Ctrl+Shift+Z after it and after a
finished Decode (the avatar and its decoded frames stay), undo past Load Avatar and redo (the
decoded frames come back with it), LOD by hand and by the camera-distance driver while the
camera moves and the timeline plays, and from another camera made active during playback,
undo and redo of Drive LOD and of a PLY export; then a crowd: Shift+D of a head, Load
Avatar on both heads at once, Alt+D of an avatar's head, Decode Frames of all three in one
pass with undo and redo, the scene's LOD bias and Gaussian budget; save.

    blender --python scene_workflow.py -- SEQUENCE.npz AVATAR.npz OUT.blend
"""

import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, script_args  # noqa: E402

SEQUENCE, AVATAR, BLEND = (Path(p) for p in script_args()[:3])
HEAD = SEQUENCE.stem


def import_file(ui):
    yield from ui_steps.file_browser(ui, "archhead.import_sequence", SEQUENCE)
    yield from ui.wait_until(lambda: HEAD in bpy.data.objects, 10, "the imported head")
    head = bpy.data.objects[HEAD]
    ui.data["imported"] = sorted(o.name for o in bpy.data.objects)
    check(bpy.context.view_layer.objects.active == head.parent, "the imported rig is not active")
    check(head.select_get() and head.parent.select_get(), "the head and rig are not selected")
    check(not bpy.data.objects["Cube"].select_get(), "the cube stayed selected")
    camera = bpy.data.objects[f"{HEAD}_camera"]
    check(camera.animation_data is None, "the fixed tracked camera is keyed")
    yield 0.5
    ui.screenshot("imported")


def panel_with_head(ui):
    yield from ui.show_sidebar()
    ui.frame_selected()
    yield 0.3
    ui.screenshot("panel_head", area_type="VIEW_3D")


def undo_import(ui):
    yield from ui_steps.undo_redo(ui, lambda: HEAD in bpy.data.objects, "the imported head")


def _scene_state(head) -> dict:
    """What a failed Load Avatar must leave as it was."""
    state = {kind: sorted(getattr(bpy.data, kind).keys()) for kind in DATA_KINDS}
    state["head display"] = head.display_type
    avatar = bpy.data.objects.get(f"{HEAD}_avatar")
    if avatar is not None:
        state["checkpoint"] = avatar.archhead_avatar.checkpoint
        state["points"] = len(avatar.data.vertices)
    return state


DATA_KINDS = ("objects", "meshes", "materials", "node_groups")


def _failing_load(ui, path: Path, what: str):
    """Load Avatar (`path`) with the points' first refresh failing, as a checkpoint the head
    accepts but the decode cannot use would: the operator reports and cancels, and the scene
    is as it was."""
    from archhead_blender import avatar_objects

    head = bpy.data.objects[HEAD]
    before = _scene_state(head)
    real = avatar_objects.refresh_avatar

    def failing(*_args, **_kwargs):
        raise ValueError("injected decode failure (the UI suite)")

    avatar_objects.refresh_avatar = failing
    try:
        result = ui.op("archhead.load_avatar", filepath=str(path))
    except RuntimeError as exc:  # an operator run from Python raises what it reported
        result = str(exc)
    finally:
        avatar_objects.refresh_avatar = real
    check("injected decode failure" in str(result), f"a failed {what} gave {result!r}")
    yield 0.3
    after = _scene_state(head)
    changed = {k: (before[k], after.get(k)) for k in before if before[k] != after.get(k)}
    check(not changed, f"a failed {what} changed the scene: {changed}")


def failed_load(ui):
    yield from _failing_load(ui, AVATAR, "Load Avatar")
    check(f"{HEAD}_avatar" not in bpy.data.objects, "a failed Load Avatar left an avatar")


def failed_replace(ui):
    other = BLEND.parent / "replacement_avatar.npz"
    other.write_bytes(AVATAR.read_bytes())
    yield from _failing_load(ui, other, "Replace Checkpoint")


def load(ui):
    yield from ui_steps.file_browser(ui, "archhead.load_avatar", AVATAR)
    name = f"{HEAD}_avatar"
    yield from ui.wait_until(lambda: name in bpy.data.objects, 10, "the avatar object")
    count = len(bpy.data.objects[name].data.vertices)
    check(count > 1000, f"the avatar shows {count} Gaussians")
    ui.data["gaussians_loaded"] = count
    yield 0.5
    ui.screenshot("avatar_loaded")


def undo_load(ui):
    name = f"{HEAD}_avatar"
    yield from ui_steps.undo_redo(ui, lambda: name in bpy.data.objects, "the avatar")
    yield from ui.wait_until(
        lambda: len(bpy.data.objects[name].data.vertices) > 1000, 5, "points after redo"
    )


def decode_cancel(ui):
    from archhead_blender.state import STATE

    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    avatar.archhead_avatar.decode_frames = "ALL"
    avatar.archhead_avatar.lod = 1.0  # software OpenGL draws LOD 0 slowly
    ui.op("archhead.decode_avatar", invoke=True)
    uid = avatar.session_uid
    total = STATE.decode_progress[uid]["total"]
    check(total >= 10, f"only {total} frames to decode")
    yield from ui.wait_until(
        lambda: STATE.decode_progress[uid]["done"] >= total // 2, 20, "half of the frames"
    )
    ui.screenshot("decode_progress")
    ui.op("archhead.cancel_decode")
    yield from ui.wait_until(lambda: uid not in STATE.decode_progress, 5, "the decode to stop")
    done = len(ui_steps.avatar_session(avatar).decoded)
    check(0 < done < total, f"cancelled decode kept {done} of {total} frames")
    ui.data["decode"] = {"total": total, "done_at_cancel": done}
    ui.screenshot("decode_cancelled")


def _avatar_and_frames():
    """What an undo after Decode Frames must keep: the avatar, its points, its decoded frames."""
    avatar = bpy.data.objects.get(f"{HEAD}_avatar")
    if avatar is None:
        return None
    decoded = sorted(ui_steps.avatar_session(avatar).decoded)
    return {"points": len(avatar.data.vertices) > 1000, "decoded": decoded}


def undo_decode_cancelled(ui):
    """A cancelled decode that kept frames is an undo step: Ctrl+Z takes it (not Load Avatar)
    back, the avatar and its decoded frames stay; Ctrl+Shift+Z the same."""
    kept = yield from ui_steps.undo_redo_keeps(ui, _avatar_and_frames, "a cancelled decode")
    check(kept and kept["decoded"], f"nothing decoded before the undo: {kept}")


def decode_and_undo(ui):
    """Decode Frames to the end (every 8th frame), then Ctrl+Z / Ctrl+Shift+Z right after."""
    from archhead_blender.state import STATE

    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    avatar.archhead_avatar.decode_frames = "STRIDE"
    avatar.archhead_avatar.stride = 8
    ui.op("archhead.decode_avatar", invoke=True)
    uid = avatar.session_uid
    decoding = STATE.decode_progress
    yield from ui.wait_until(lambda: uid not in decoding, 15, "the decode to finish")
    kept = yield from ui_steps.undo_redo_keeps(ui, _avatar_and_frames, "Decode Frames")
    scene = bpy.context.scene
    want = list(range(scene.frame_start, scene.frame_end + 1, 8))
    check(kept and kept["decoded"] == want, f"decoded {kept}, want frames {want}")
    ui.data["decode_undo"] = kept["decoded"]
    avatar = bpy.data.objects[f"{HEAD}_avatar"]  # undo and redo made new Python objects
    avatar.archhead_avatar.decode_frames = "ALL"
    ui.screenshot("decode_redone")


def undo_past_load(ui):
    """Ctrl+Z until Load Avatar itself is undone (the avatar object gone), then Ctrl+Shift+Z
    as many times: the avatar comes back with the frames it had decoded."""
    name = f"{HEAD}_avatar"
    before = _avatar_and_frames()
    check(before and before["decoded"], f"nothing decoded before the undo: {before}")
    presses = 0
    while name in bpy.data.objects:
        check(presses < 4, "four Ctrl+Z did not undo Load Avatar")
        ui.key("Z", ctrl=True)
        presses += 1
        yield 1.0
    for _ in range(presses):
        ui.key("Z", ctrl=True, shift=True)
        yield 1.0
    yield from ui.wait_until(lambda: name in bpy.data.objects, 5, "the avatar after the redos")
    after = _avatar_and_frames()
    check(after == before, f"{presses} x undo and redo: {after}, before {before}")
    ui.data["undo_past_load"] = {"presses": presses, "decoded": after["decoded"]}


def lod_by_hand(ui):
    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    counts = {}
    for lod in (0.0, 1.0):
        avatar.archhead_avatar.lod = lod
        yield from ui.wait_until(
            lambda lod=lod: ui_steps.shows_lod(avatar, lod), 10, f"the points at LOD {lod:g}"
        )
        counts[lod] = len(avatar.data.vertices)
        ui.frame_selected()
        yield 0.3
        ui.screenshot(f"viewport_lod{lod:g}", area_type="VIEW_3D")
    check(counts[0.0] > 5 * counts[1.0], f"Gaussians at LOD 0 / 1: {counts}")
    ui.data["gaussians_by_lod"] = counts


def lod_driver_playback(ui):
    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    scene = bpy.context.scene
    # from LOD 1 to about 0.2 (fewer Gaussians to draw with software OpenGL than LOD 0)
    dolly = ui_steps.dolly_camera(scene, bpy.data.objects[HEAD], far=3.5, near=1.0)
    scene.camera = dolly
    ui.op("archhead.drive_lod", near=0.5, far=3.0)
    check(avatar.animation_data and avatar.animation_data.drivers, "no LOD driver")
    scene.frame_set(scene.frame_start)
    seen = {}  # every frame playback reached (a handler: a loaded machine's timer misses some)

    def reached(scene, depsgraph):
        lod = avatar.evaluated_get(depsgraph).archhead_avatar.lod
        seen[scene.frame_current] = float(lod)

    sync = scene.sync_mode
    scene.sync_mode = "NONE"  # Play Every Frame: no frame dropped however slow the drawing
    bpy.app.handlers.frame_change_post.append(reached)
    with ui.context("VIEW_3D"):
        bpy.ops.screen.animation_play()
    try:
        yield from ui.wait_until(
            lambda: scene.frame_end - 1 in seen, 30, "playback to reach the end", poll=0.05
        )
    finally:
        with ui.context("VIEW_3D"):
            bpy.ops.screen.animation_cancel(restore_frame=False)
        bpy.app.handlers.frame_change_post.remove(reached)
        scene.sync_mode = sync
    seen = {f: lod for f, lod in seen.items() if f < scene.frame_end}  # a wrap to the start
    ui.data["driven_lod"] = {str(k): round(v, 3) for k, v in sorted(seen.items())}
    check(len(seen) >= 3, f"playback showed only frames {sorted(seen)}")
    lods = [seen[f] for f in sorted(seen)]
    check(lods[0] > 0.9 and lods[-1] < 0.35, f"driven LOD did not follow the dolly: {lods}")
    check(lods == sorted(lods, reverse=True), f"driven LOD not falling as the camera nears: {lods}")
    # what the points show follows the driver
    yield from ui.wait_until(
        lambda: ui_steps.shows_lod(avatar, ui_steps.evaluated_lod(avatar)),
        10,
        "the points to show the driven LOD",
    )
    ui.screenshot("driver_end_of_playback", area_type="VIEW_3D")


def driver_follows_active_camera(ui):
    """While the timeline plays, the artist makes another camera active (Ctrl+Numpad0 on it):
    the driver measures from that camera from then on."""
    import mathutils

    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    scene = bpy.context.scene
    centre = ui_steps.head_centre(bpy.data.objects[HEAD])
    near = bpy.data.objects.new("ui_near", bpy.data.cameras.new("ui_near"))
    scene.collection.objects.link(near)
    near.rotation_euler = (1.5708, 0.0, 0.0)
    near.location = centre - mathutils.Vector((0.0, 1.25, 0.0))  # LOD (1.25 - 0.5) / 2.5
    want = (1.25 - 0.5) / (3.0 - 0.5)
    check(scene.camera.name == "ui_dolly", f"the active camera is {scene.camera.name}")
    scene.frame_set(scene.frame_start)  # the dolly at 3.5 m: LOD 1
    sync = scene.sync_mode
    scene.sync_mode = "NONE"  # Play Every Frame
    with ui.context("VIEW_3D"):
        bpy.ops.screen.animation_play()
    try:
        yield from ui.wait_until(
            lambda: scene.frame_current != scene.frame_start, 2, "playback to start"
        )
        before = ui_steps.evaluated_lod(avatar)
        check(before > 0.8, f"LOD {before:.3f} from the dolly's start")
        for obj in bpy.context.selected_objects:
            obj.select_set(False)
        bpy.context.view_layer.objects.active = near
        ui.op("view3d.object_as_camera")  # Ctrl+Numpad0: the active object becomes the camera
        check(scene.camera == near, "Ctrl+Numpad0 did not make ui_near the scene camera")
        yield from ui.wait_until(
            lambda: abs(ui_steps.evaluated_lod(avatar) - want) < 0.05,
            2,
            f"the driven LOD to follow ui_near ({want:.3f})",
        )
        # not the dolly coming near: it is still far away
        dolly = (bpy.data.objects["ui_dolly"].matrix_world.translation - centre).length
        check(dolly > 2.0, f"the dolly is {dolly:.2f} m away: no test of the switch")
        check(bpy.context.screen.is_animation_playing, "playback stopped")
        frame = scene.frame_current
        yield from ui.wait_until(
            lambda: scene.frame_current != frame, 2, "the timeline to go on playing"
        )
        lod = ui_steps.evaluated_lod(avatar)  # the dolly still moves; the LOD stays
        check(abs(lod - want) < 0.05, f"LOD {lod:.3f} moved with the inactive dolly")
        yield from ui.wait_until(
            lambda: ui_steps.shows_lod(avatar, ui_steps.evaluated_lod(avatar)),
            10,
            "the points to show the new camera's LOD",
        )
    finally:
        with ui.context("VIEW_3D"):
            bpy.ops.screen.animation_cancel(restore_frame=False)
        scene.sync_mode = sync
    ui.data["camera_switch"] = {"before": round(before, 3), "after": round(lod, 3)}
    ui.screenshot("driver_after_camera_switch", area_type="VIEW_3D")
    scene.camera = bpy.data.objects["ui_dolly"]  # as the saved file had it


def undo_drive_lod(ui):
    """Drive LOD again with other distances (its dialog's OK pushes an undo step): Ctrl+Z
    brings the first driver's back, Ctrl+Shift+Z the new ones."""
    from archhead_blender.lod_driver import NEAR_PROP

    name = f"{HEAD}_avatar"
    _select(bpy.data.objects[name])  # the last step left the new camera active
    ui.op("archhead.drive_lod", undo=True, near=0.6, far=3.1)

    def redriven():  # an undo may go back past the first driver too (it made no undo step)
        return abs(bpy.data.objects[name].get(NEAR_PROP, 0.0) - 0.6) < 1e-6

    yield from ui_steps.undo_redo(ui, redriven, "Drive LOD's new near distance")
    avatar = bpy.data.objects[name]
    check(avatar.animation_data.drivers, "no LOD driver after the redo")
    _select(avatar)  # undo and redo made new Python objects
    ui.op("archhead.drive_lod", undo=True, near=0.5, far=3.0)  # as the saved file had it


def export_ply(ui):
    """Export Gaussians (PLY) of the current frame, then Ctrl+Z and Ctrl+Shift+Z: the export
    makes no undo step of its own, and the avatar, its points and decoded frames stay."""
    name = f"{HEAD}_avatar"
    _select(bpy.data.objects[name])
    path = BLEND.parent / "ui_export.ply"
    path.unlink(missing_ok=True)
    ui.op("archhead.export_ply", filepath=str(path))
    check(path.is_file(), "no PLY written")
    header = path.read_bytes()[:400].split(b"end_header")[0].decode("ascii", "replace")
    count = int(header.split("element vertex ")[1].split()[0])
    check(count > 1000, f"the PLY holds {count} Gaussians")
    ui.data["ply_gaussians"] = count
    yield from ui_steps.undo_redo_keeps(ui, _avatar_and_frames, "Export PLY")
    check(path.is_file(), "an undo removed the exported file")


def _select(*objects, active=None):
    for obj in bpy.context.selected_objects:
        obj.select_set(False)
    for obj in objects:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = active or objects[0]


def _duplicate(ui, objects, linked: bool):
    """Shift+D (Alt+D) over the 3D view, then Return where the pointer is: the copies stay
    where the originals are. Returns the copies' names in the order of `objects` (each the
    copy of the same role: head, rig, avatar)."""
    before = set(bpy.data.objects.keys())
    _select(*objects)
    ui.key("D", shift=not linked, alt=linked)
    yield from ui.wait_until(lambda: set(bpy.data.objects.keys()) - before, 5, "the copies")
    yield 0.3
    ui.key("RET")  # ends the grab that follows a duplicate, without a move
    yield from ui.wait_until(lambda: not _transforming(ui), 5, "the grab to end")
    new = {_role(bpy.data.objects[n]): n for n in set(bpy.data.objects.keys()) - before}
    check(len(new) == len(objects), f"the copies: {sorted(new.values())}")
    return [new[_role(o)] for o in objects]


def _role(obj) -> str:
    if obj.archhead_avatar.checkpoint:
        return "avatar"
    return "head" if "archhead_model_id" in obj else obj.type


def _transforming(ui) -> bool:
    """Whether the grab that follows a duplicate is still running."""
    running = getattr(ui.window, "modal_operators", ())  # Blender 4.2 and later
    return any(op.bl_idname.startswith("TRANSFORM") for op in running)


def crowd(ui):
    from archhead_blender.avatar_objects import avatar_of, head_of
    from archhead_blender.state import STATE

    head = bpy.data.objects[HEAD]
    names = yield from _duplicate(ui, [head, head.parent], linked=False)
    head = bpy.data.objects[HEAD]  # after an operator, fresh Python objects
    copy_head, copy_rig = (bpy.data.objects[n] for n in names)
    check(head_of(copy_rig) is copy_head, "Shift+D's rig names the original head")
    check(avatar_of(copy_head) is None, "the head's copy has an avatar before Load Avatar")
    copy_rig.location.x += 0.5
    _select(head, copy_head, active=copy_head)
    yield from ui_steps.file_browser(ui, "archhead.load_avatar", AVATAR)
    yield from ui.wait_until(lambda: avatar_of(copy_head) is not None, 10, "the copy's avatar")
    check(len(STATE.decoders) == 1, f"{len(STATE.decoders)} decoders for one checkpoint")

    # Alt+D of the copy's head, rig and avatar: a linked head with points of its own
    copy_avatar = avatar_of(copy_head)
    names = yield from _duplicate(ui, [copy_head, copy_rig, copy_avatar], linked=True)
    head, copy_head, copy_rig = (bpy.data.objects[n] for n in (HEAD, copy_head.name, copy_rig.name))
    copy_avatar = avatar_of(copy_head)
    linked = [bpy.data.objects[n] for n in names]
    linked[1].location.x -= 1.0
    yield from ui.wait_until(
        lambda: linked[2].data is not copy_avatar.data and linked[2].data.users == 1,
        5,
        "the linked copy's own point mesh",
    )
    avatars = [avatar_of(head), copy_avatar, linked[2]]
    check(len({a.name for a in avatars}) == 3, f"avatars {[a.name for a in avatars]}")
    copies = [copy_head.name, copy_rig.name, linked[0].name, linked[1].name]  # heads and rigs
    for obj in avatars:
        obj.archhead_avatar.lod = 1.0  # software OpenGL draws LOD 1 fastest
        obj.archhead_avatar.decode_frames = "STRIDE"
        obj.archhead_avatar.stride = 8
    _select(head, copy_head, linked[0], active=head)
    yield 0.3
    ui.screenshot("crowd", area_type="VIEW_3D")

    # Decode Frames with the three heads selected: one pass decodes them all
    ui.op("archhead.decode_avatar", invoke=True)
    uids = [a.session_uid for a in avatars]
    yield from ui.wait_until(
        lambda: not any(u in STATE.decode_progress for u in uids), 15, "the crowd's decode"
    )
    names = [a.name for a in avatars]

    def decoded():
        found = [bpy.data.objects.get(n) for n in names]
        if None in found:
            return None
        return [sorted(ui_steps.avatar_session(a).decoded) for a in found]

    kept = yield from ui_steps.undo_redo_keeps(ui, decoded, "the crowd's Decode Frames")
    scene = bpy.context.scene
    want = list(range(scene.frame_start, scene.frame_end + 1, 8))
    check(kept == [want] * 3, f"decoded {kept}, want {want} for each avatar")

    # the scene's settings for all of them: LOD bias (drivers) and the Gaussian budget
    avatars = [bpy.data.objects[n] for n in names]
    scene.frame_set(scene.frame_start)  # the dolly 3.5 m away: the driven avatar at LOD 1
    base = ui_steps.evaluated_lod(avatars[0])
    scene.archhead_crowd.lod_bias = -0.5
    biased = ui_steps.evaluated_lod(avatars[0])
    scene.archhead_crowd.lod_bias = 0.0
    # the dolly 3.5 m from the head's centre, a little more from its root bone: about 1.2
    # before the clamp, 0.7 after the bias
    ok = base > 0.99 and 0.65 < biased < 0.8
    check(ok, f"LOD {base:.3f}, biased by -0.5: {biased:.3f}")
    for obj in avatars:
        obj.archhead_avatar.lod = 0.0
    yield from ui.wait_until(
        lambda: all(ui_steps.shows_lod(a, ui_steps.evaluated_lod(a)) for a in avatars),
        10,
        "the avatars at their levels",
    )
    free = sum(len(a.data.vertices) for a in avatars)
    scene.archhead_crowd.gaussian_budget = budget = free // 2
    yield from ui.wait_until(
        lambda: sum(len(a.data.vertices) for a in avatars) <= budget, 10, "the budget"
    )
    ui.screenshot("crowd_budget", area_type="VIEW_3D")
    ui.data["crowd"] = {
        "gaussians_free": free,
        "gaussians_budgeted": sum(len(a.data.vertices) for a in avatars),
        "decoded_frames": kept[0],
    }
    scene.archhead_crowd.gaussian_budget = 0
    head = bpy.data.objects[HEAD]  # the undo and redo made new Python objects
    avatar_of(head).archhead_avatar.decode_frames = "ALL"
    for name in [*copies, *names[1:]]:  # the scene as it was before the crowd
        bpy.data.objects.remove(bpy.data.objects[name])
    _select(head, head.parent, active=head.parent)


def save(ui):
    with ui.context(None):
        bpy.ops.wm.save_as_mainfile(filepath=str(BLEND))
    check(BLEND.is_file(), f"{BLEND} not written")


run_steps(
    [
        ("File > Import", import_file),
        ("panel with the head", panel_with_head),
        ("undo and redo the import", undo_import),
        ("a failed Load Avatar leaves the scene as it was", failed_load),
        ("Load Avatar", load),
        ("undo and redo Load Avatar", undo_load),
        ("a failed Replace Checkpoint keeps the avatar", failed_replace),
        ("modal Decode, cancelled half way", decode_cancel),
        ("undo and redo a cancelled Decode", undo_decode_cancelled),
        ("Decode Frames, then undo and redo", decode_and_undo),
        ("undo past Load Avatar, redo: the decoded frames stay", undo_past_load),
        ("LOD by hand", lod_by_hand),
        ("LOD driver during playback", lod_driver_playback),
        ("LOD driver follows the camera made active", driver_follows_active_camera),
        ("undo and redo Drive LOD", undo_drive_lod),
        ("Export PLY, then undo and redo", export_ply),
        ("a crowd: duplicates, Load and Decode on all, undo, bias and budget", crowd),
        ("save", save),
    ]
)
