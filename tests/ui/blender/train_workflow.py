"""Train Avatar from the panel on a tiny subject: progress in the panel and the status bar,
Cancel half way, the backend gone (no orphan), the saved checkpoint loaded onto the head,
and Ctrl+Z / Ctrl+Shift+Z right after take that load back and redo it.

    blender --python train_workflow.py -- SUBJECT_DIR CONFIG.json OUT_DIR
"""

import os
import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, script_args  # noqa: E402

SUBJECT, CONFIG, RUN = (Path(p) for p in script_args()[:3])
HEAD = "tracking"  # the head is named after the tracking file


def current_run():
    from archhead_blender.training import current_run

    return current_run()


def import_subject(ui):
    yield from ui_steps.file_browser(ui, "archhead.import_sequence", SUBJECT / "tracking.npz")
    yield from ui.wait_until(lambda: HEAD in bpy.data.objects, 10, "the imported head")
    yield from ui.show_sidebar()


def train_and_cancel(ui):
    run = ui_steps.start_training(ui, SUBJECT, CONFIG, RUN)
    pid = ui.data["backend_pid"]
    ui.screenshot("training_starting")
    yield from ui.wait_until(lambda: run.status.step >= 3, 30, "three training steps")
    yield 1.0
    ui.data["progress"] = run.summary()
    # the sidebar's lines fit its default width (about 32 characters; the screenshot shows
    # them whole)
    lines = [run.bar_text(), run.rate_text(), *run.loss_lines()]
    ui.data["panel_lines"] = lines
    check(len(lines) >= 4, f"the Training box shows only {lines}")
    long = [line for line in lines if len(line) > 32]
    check(not long, f"Training box lines wider than the default sidebar: {long}")
    ui.screenshot("training_progress")
    ui.op("archhead.cancel_training")
    yield 0.3
    ui.screenshot("training_stopping")
    yield from ui.wait_until(lambda: current_run() is None, 20, "the run to end")
    yield 0.5
    check(not os.path.exists(f"/proc/{pid}"), f"backend {pid} still running after cancel")
    avatar = bpy.data.objects.get(f"{HEAD}_avatar")
    check(avatar is not None, "the stopped run's checkpoint was not loaded")
    ui.data["gaussians"] = len(avatar.data.vertices)
    ui.screenshot("training_stopped_avatar_loaded")


def undo_after_training(ui):
    """Loading the run's avatar is an undo step of its own: Ctrl+Z takes it back (the head
    stays), Ctrl+Shift+Z brings it back with its points."""
    name = f"{HEAD}_avatar"
    yield from ui_steps.undo_redo(ui, lambda: name in bpy.data.objects, "the trained avatar")
    check(HEAD in bpy.data.objects, "Ctrl+Z after training removed the head too")
    yield from ui.wait_until(
        lambda: len(bpy.data.objects[name].data.vertices) > 0, 5, "the avatar's points"
    )


run_steps(
    [
        ("import the subject's tracking", import_subject),
        ("Train Avatar with progress and Cancel", train_and_cancel),
        ("Ctrl+Z after training", undo_after_training),
    ]
)
