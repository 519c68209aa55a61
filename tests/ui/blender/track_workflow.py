"""Track Video from the panel on a short real clip: the dialog confirmed with Return, a run
cancelled half way (its backend gone, no output folder), then a run to the end with its
progress in the panel, imported as a rigged, shape-keyed head; Ctrl+Z takes the head away and
Ctrl+Shift+Z brings it back.

    blender --python track_workflow.py -- VIDEO OUT_DIR FRAMES
"""

import os
import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, script_args  # noqa: E402

VIDEO, OUT = (Path(p) for p in script_args()[:2])
FRAMES = int(script_args()[2])
SIZE = 192  # small crops: the test times the workflow, not the tracker


def current_tracking():
    from archhead_blender.tracking import current_tracking

    return current_tracking()


def track_from_dialog(ui, out_dir: Path, frames: int = FRAMES):
    """Track Video as its panel button runs it (invoke: the dialog, filled in), confirmed
    with Return where the dialog opened."""
    area = ui.area("VIEW_3D")
    x, y = area.x + area.width // 2, area.y + area.height // 2
    ui.window.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
    yield 0.2
    ui.op(
        "archhead.track_video",
        invoke=True,
        video=str(VIDEO),
        out_dir=str(out_dir),
        frames=frames,
        size=SIZE,
    )
    yield 0.5
    ui.screenshot(f"track_dialog_{out_dir.name}")
    ui.window.event_simulate(type="RET", value="PRESS", x=x, y=y)
    ui.window.event_simulate(type="RET", value="RELEASE", x=x, y=y)
    yield from ui.wait_until(lambda: current_tracking() is not None, 5, "the tracking run")
    run = current_tracking()
    ui.data.setdefault("backend_pids", []).append(run.backend.process.pid)
    return run


def cancel_half_way(ui):
    yield from ui.show_sidebar()
    out_dir = OUT / "cancelled"
    # four times the frames, cancelled half way through detecting them: the fit and the
    # writing take seconds, and a cancel sent once the fit had started (after a screenshot)
    # once arrived after the run had finished
    run = yield from track_from_dialog(ui, out_dir, 4 * FRAMES)
    pid = run.backend.process.pid

    def half_detected():
        s = run.status
        return s.stage == "fit" or (s.stage == "detect" and s.step >= s.total // 2 > 0)

    yield from ui.wait_until(half_detected, 20, "half the frames detected", poll=0.1)
    ui.op("archhead.cancel_tracking")
    ui.screenshot("tracking_progress", area_type="VIEW_3D")
    yield from ui.wait_until(lambda: current_tracking() is None, 10, "the run to stop")
    yield 0.5
    check(not os.path.exists(f"/proc/{pid}"), f"tracking backend {pid} still running")
    check(not out_dir.exists(), f"a cancelled run left {out_dir}")
    check("cancelled" not in bpy.data.objects, "a cancelled run imported a head")


def track_to_the_end(ui):
    out_dir = OUT / "clip"
    run = yield from track_from_dialog(ui, out_dir)
    seen = []  # (stage, fraction) as the panel showed them

    def progressed():
        if run.status.stage and (not seen or seen[-1][0] != run.status.stage):
            seen.append((run.status.stage, round(run.fraction, 3)))
            ui.screenshot(f"tracking_{run.status.stage}", area_type="VIEW_3D")
        return current_tracking() is None

    yield from ui.wait_until(progressed, 40, "the tracking to finish", poll=0.3)
    ui.data["stages"] = seen
    # in order, first to last (a loaded machine's window can miss a stage of a second)
    stages = ["detect", "fit", "write", "refine", "masks"]
    shown = [s for s, _ in seen]
    check(
        shown[0] == stages[0]
        and shown[-1] == stages[-1]
        and shown == sorted(shown, key=stages.index),
        f"stages shown: {seen}",
    )
    fractions = [f for _, f in seen]
    check(fractions == sorted(fractions), f"progress went back: {seen}")
    head = bpy.data.objects.get("clip")
    check(head is not None, f"no imported head; objects: {sorted(bpy.data.objects.keys())}")
    rig = head.parent
    check(rig is not None and rig.type == "ARMATURE", "the tracked head has no rig")
    keys = head.data.shape_keys.key_blocks.keys() if head.data.shape_keys else []
    check(any(k.startswith("expr_") for k in keys), f"no expression shape keys: {keys[:5]}")
    check(rig.animation_data and rig.animation_data.action, "the rig is not animated")
    scene = bpy.context.scene
    ui.data["frames"] = [scene.frame_start, scene.frame_end]
    check(scene.frame_end - scene.frame_start + 1 == FRAMES, f"frame range {ui.data['frames']}")
    check((out_dir / "tracking.npz").is_file(), "no tracking.npz in the training folder")
    bpy.data.objects["Cube"].hide_set(True)  # the head sits at the origin, inside it
    ui.frame_selected()
    yield 0.3
    ui.screenshot("tracked_head_imported", area_type="VIEW_3D")


def undo_track(ui):
    """The run's import is an undo step of its own (BackendWatch pushes it)."""
    yield from ui_steps.undo_redo(ui, lambda: "clip" in bpy.data.objects, "the tracked head")
    head = bpy.data.objects["clip"]
    check(head.data.shape_keys is not None, "the tracked head came back without shape keys")


run_steps(
    [
        ("Track Video, cancelled half way", cancel_half_way),
        ("Track Video to the end", track_to_the_end),
        ("undo and redo Track Video", undo_track),
    ]
)
