"""After Blender quit during training (train_quit.py): Train Avatar on the same frames,
tracking and Output with Resume ticked goes on from the saved step, as the quit message said.

    blender --python train_resume.py -- SUBJECT_DIR CONFIG.json OUT_DIR STEP_AT_QUIT
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, script_args  # noqa: E402

SUBJECT, CONFIG, RUN = (Path(p) for p in script_args()[:3])
STEP_AT_QUIT = int(script_args()[3])


def resume(ui):
    from archhead_blender.training import current_run

    ui.op("archhead.import_sequence", filepath=str(SUBJECT / "tracking.npz"))
    run = ui_steps.start_training(ui, SUBJECT, CONFIG, RUN, resume=True)
    yield from ui.wait_until(lambda: run.status.total > 0, 20, "the resumed run to start")
    first = run.status.step
    ui.data["first_step"] = first
    check(first >= STEP_AT_QUIT, f"resumed at step {first}, quit at {STEP_AT_QUIT}")
    yield from ui.wait_until(lambda: run.status.step > first, 10, "a step after resuming")
    ui.op("archhead.cancel_training")
    yield from ui.wait_until(lambda: current_run() is None, 20, "the run to end")


run_steps([("Train Avatar with Resume", resume)])
