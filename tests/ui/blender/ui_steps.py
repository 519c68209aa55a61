"""Pieces the UI test scripts share: the file browser, undo / redo by the keyboard, what an
avatar shows, a camera dolly, Train Avatar on the tiny subject."""

from __future__ import annotations

from pathlib import Path

import bpy
from ui_driver import check


def _file_browser():
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "FILE_BROWSER":
                return window, area
    return None


def file_browser(ui, idname: str, path: Path):
    """Open `idname`'s file browser as its button does, pick `path` in it (folder and file
    name fields), press Return."""
    ui.op(idname, invoke=True)
    yield from ui.wait_until(lambda: _file_browser() is not None, 5, "the file browser")
    yield 0.5
    window, area = _file_browser()
    params = area.spaces.active.params
    params.directory = str(path.parent).encode()
    params.filename = path.name
    yield 0.5
    ui.screenshot(f"file_browser_{idname.split('.')[1]}", window=window)
    ui.key("RET", window=window, area=area)  # Return in the file list: Accept
    yield from ui.wait_until(lambda: _file_browser() is None, 15, "the file browser to close")


def undo_redo(ui, present, what: str):
    """Ctrl+Z takes `what` away, Ctrl+Shift+Z brings it back (keys typed over the 3D view)."""
    check(present(), f"{what} missing before undo")
    ui.key("Z", ctrl=True)
    yield from ui.wait_until(lambda: not present(), 5, f"Ctrl+Z to remove {what}")
    ui.key("Z", ctrl=True, shift=True)
    yield from ui.wait_until(present, 5, f"Ctrl+Shift+Z to bring back {what}")
    yield 0.3


def undo_redo_keeps(ui, state, what: str):
    """Ctrl+Z, then Ctrl+Shift+Z (keys typed over the 3D view), each waited for through
    Blender's undo_post / redo_post handlers: `state()` (what must survive both, e.g. the
    avatar and its decoded frames) is the same after each as before."""
    calls = {"undo": 0, "redo": 0}

    def on_undo(*_args):
        calls["undo"] += 1

    def on_redo(*_args):
        calls["redo"] += 1

    before = state()
    bpy.app.handlers.undo_post.append(on_undo)
    bpy.app.handlers.redo_post.append(on_redo)
    try:
        for kind, shift in (("undo", False), ("redo", True)):
            ui.key("Z", ctrl=True, shift=shift)
            yield from ui.wait_until(lambda kind=kind: calls[kind] > 0, 5, f"the {kind}")
            yield 0.3
            after = state()
            check(after == before, f"{kind} after {what}: {after}, before {before}")
    finally:
        bpy.app.handlers.undo_post.remove(on_undo)
        bpy.app.handlers.redo_post.remove(on_redo)
    return before


def avatar_session(obj):
    from archhead_blender.avatar_session import session

    return session(obj)


def evaluated_lod(obj) -> float:
    depsgraph = bpy.context.evaluated_depsgraph_get()
    return float(obj.evaluated_get(depsgraph).archhead_avatar.lod)


def avatar_codes(obj):
    """The FLAME codes the avatar reads from its head at the current frame."""
    from archhead_blender.scene_state import frame_codes

    depsgraph = bpy.context.evaluated_depsgraph_get()
    return frame_codes(obj.archhead_avatar.head, depsgraph, avatar_session(obj).joint_dirs)


def shows_lod(obj, lod: float) -> bool:
    """Whether the points hold the avatar's current frame at level of detail `lod`."""
    current = avatar_session(obj)
    if current.shown is None:
        return False
    return current.shown[0] == current.shared.key(avatar_codes(obj), lod)


def head_centre(head):
    import mathutils

    corners = [head.matrix_world @ mathutils.Vector(c) for c in head.bound_box]
    return sum(corners, mathutils.Vector()) / 8


def dolly_camera(scene, head, far: float, near: float, name="ui_dolly"):
    """A new camera looking at the head along -Y, from `far` metres at the first frame to
    `near` at the last."""
    import mathutils

    centre = head_centre(head)
    camera = bpy.data.objects.new(name, bpy.data.cameras.new(name))
    scene.collection.objects.link(camera)
    camera.rotation_euler = (1.5708, 0.0, 0.0)  # looks along +Y
    for frame, distance in ((scene.frame_start, far), (scene.frame_end, near)):
        camera.location = centre - mathutils.Vector((0.0, distance, 0.0))
        camera.keyframe_insert("location", frame=frame)
    return camera


def start_training(
    ui, subject: Path, config: Path, out: Path, resume: bool = False, minutes: float = 0.0
):
    """Train Avatar on a tracked folder (frames/, tracking.npz) with a base config (with
    `resume`, Resume ticked; `minutes`, a Time limit); returns the run, its backend's pid
    kept in ui.data for the orphan check."""
    from archhead_blender.training import current_run

    ui.op(
        "archhead.train_avatar",
        frames_dir=str(subject / "frames"),
        tracking=str(subject / "tracking.npz"),
        out_dir=str(out),
        base_config=str(config),
        **({"resume": True} if resume else {}),  # unset otherwise, as the dialog leaves it
        **({"minutes": minutes} if minutes else {}),
    )
    run = current_run()
    check(run is not None, f"no training run after Train Avatar{' with Resume' * resume}")
    ui.data["backend_pid"] = run.backend.process.pid
    return run
