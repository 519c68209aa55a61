"""Avatar from Video from the panel on a short real clip with the demo preset.

blender --python video_avatar.py -- VIDEO OUT_DIR FRAMES cancel
    the dialog confirmed with Return; one progress display over tracking and training;
    Cancel during training (the backend saves and exits; the head stays, no avatar)
blender --python video_avatar.py -- VIDEO OUT_DIR FRAMES resume
    a new Blender after that: Avatar from Video on the same Output skips the tracking,
    imports the tracked head, resumes the training to the end and loads the avatar
"""

import os
import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, script_args  # noqa: E402

VIDEO, OUT = (Path(p) for p in script_args()[:2])
FRAMES, MODE = int(script_args()[2]), script_args()[3]
NAME = OUT.name  # the head is named after the output folder
SIZE = 192  # small crops: the test times the workflow, not the tracker
PRESET = "demo"


def current():
    from archhead_blender.video_avatar import current_video_run

    return current_video_run()


def panel_lines(run) -> list[str]:
    return [run.step_text(), run.bar_text(), run.detail_text()]


def start_from_dialog(ui):
    """Avatar from Video as its panel button runs it (the dialog), confirmed with Return."""
    yield from ui.show_sidebar()
    area = ui.area("VIEW_3D")
    x, y = area.x + area.width // 2, area.y + area.height // 2
    ui.window.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
    yield 0.2
    ui.op(
        "archhead.avatar_from_video",
        invoke=True,
        video=str(VIDEO),
        out_dir=str(OUT),
        preset=PRESET,
        frames=FRAMES,
        size=SIZE,
    )
    yield 0.5
    ui.screenshot("avatar_from_video_dialog")
    ui.window.event_simulate(type="RET", value="PRESS", x=x, y=y)
    ui.window.event_simulate(type="RET", value="RELEASE", x=x, y=y)
    yield from ui.wait_until(lambda: current() is not None, 5, "the Avatar from Video run")


def track_then_cancel_training(ui):
    yield from start_from_dialog(ui)
    run = current()
    check(run.stage == "track", f"a new folder starts at stage {run.stage}")
    pids = ui.data.setdefault("backend_pids", [])
    pids.append(run.tracking.backend.process.pid)
    fractions = []

    def training_going():
        if run.stage == "track" and run.tracking is not None and run.tracking.status.stage:
            fractions.append(run.fraction)
        if run.stage == "train" and run.training is not None:
            fractions.append(run.fraction)
            if run.training.backend.process.pid not in pids:
                pids.append(run.training.backend.process.pid)
                ui.screenshot("panel_training_started", area_type="VIEW_3D")
            return run.training.status.step >= 5
        if len(fractions) == 1:
            ui.screenshot("panel_tracking", area_type="VIEW_3D")
        return False

    yield from ui.wait_until(training_going, 60, "the tracking, then 5 training steps")
    check(current() is run, "the run ended before Cancel")
    check(fractions == sorted(fractions), f"the progress went back: {fractions}")
    check(0.25 < run.fraction < 1.0, f"progress {run.fraction:.3f} during training")
    check(NAME in bpy.data.objects, "the tracked head was not imported before training")
    lines = panel_lines(run)
    ui.data["panel_lines"] = lines
    long = [line for line in lines if len(line) > 32]
    check(not long, f"panel lines wider than the default sidebar: {long}")
    ui.screenshot("panel_training", area_type="VIEW_3D")
    ui.op("archhead.cancel_video_avatar")
    yield from ui.wait_until(lambda: current() is None, 20, "the run to stop")
    yield 0.5
    for pid in pids:
        check(not os.path.exists(f"/proc/{pid}"), f"backend {pid} still running after Cancel")
    check(f"{NAME}_avatar" not in bpy.data.objects, "a cancelled run loaded an avatar")
    check((OUT / "run" / "train_state.pt").is_file(), "the stopped run saved no state")
    from archhead_blender.video_avatar import folder_state

    state = folder_state(str(OUT))
    check(state == "Tracked here: resumes training", f"the dialog would say {state!r}")
    ui.data["folder_state"] = state
    ui.screenshot("cancelled", area_type="VIEW_3D")


def resume_to_the_end(ui):
    check(NAME not in bpy.data.objects, "a new file already holds the head")
    yield from ui.show_sidebar()
    ui.op(
        "archhead.avatar_from_video",
        video=str(VIDEO),
        out_dir=str(OUT),
        preset=PRESET,
        frames=FRAMES,
        size=SIZE,
    )
    run = current()
    check(run is not None, "no run after Avatar from Video")
    check(run.stage == "train", f"a tracked folder resumed at stage {run.stage}")
    check(NAME in bpy.data.objects, "the tracked head was not imported")
    ui.data["backend_pids"] = [run.training.backend.process.pid]
    yield from ui.wait_until(lambda: run.training.status.total > 0, 20, "the resumed training")
    ui.data["first_step"] = run.training.status.step
    ui.screenshot("panel_resumed", area_type="VIEW_3D")
    yield from ui.wait_until(lambda: current() is None, 40, "the training to finish")
    check(run.result and run.result[0] == "INFO", f"the run ended with {run.result}")
    avatar = bpy.data.objects.get(f"{NAME}_avatar")
    check(avatar is not None, f"no avatar; objects {sorted(bpy.data.objects.keys())}")
    count = len(avatar.data.vertices)
    check(count > 0, "the loaded avatar has no points")
    check(avatar.archhead_avatar.head == bpy.data.objects[NAME], "the avatar is on another head")
    ui.data["gaussians"] = count
    bpy.data.objects["Cube"].hide_set(True)
    for obj in bpy.context.selected_objects:
        obj.select_set(False)
    avatar.select_set(True)
    ui.frame_selected()
    yield 0.3
    ui.screenshot("avatar_loaded", area_type="VIEW_3D")


def undo_video_avatar(ui):
    """What the run added ends in one undo step: Ctrl+Z takes the avatar away, Ctrl+Shift+Z
    brings it back with its points."""
    name = f"{NAME}_avatar"
    yield from ui_steps.undo_redo(ui, lambda: name in bpy.data.objects, "the avatar")
    yield from ui.wait_until(
        lambda: len(bpy.data.objects[name].data.vertices) > 0, 10, "the avatar's points"
    )


def again_on_a_finished_folder(ui):
    """A third time on the same Output: nothing to track or train; the head in the file is
    reused (no second head) and the avatar loaded again, no backend started."""
    from archhead_blender.state import STATE

    before = sorted(bpy.data.objects.keys())
    ui.op(
        "archhead.avatar_from_video",
        video=str(VIDEO),
        out_dir=str(OUT),
        preset=PRESET,
        frames=FRAMES,
        size=SIZE,
    )
    check(STATE.tracking_run is None and STATE.training_run is None, "a backend started")
    yield from ui.wait_until(lambda: current() is None, 5, "the run to end")
    after = sorted(bpy.data.objects.keys())
    check(after == before, f"objects {before} became {after}")
    check(len(bpy.data.objects[f"{NAME}_avatar"].data.vertices) > 0, "the avatar lost its points")


if MODE == "cancel":
    run_steps([("Avatar from Video, Cancel during training", track_then_cancel_training)])
else:
    run_steps(
        [
            ("Avatar from Video again: resumed to the end", resume_to_the_end),
            ("undo and redo Avatar from Video", undo_video_avatar),
            ("Avatar from Video on a finished folder", again_on_a_finished_folder),
        ]
    )
