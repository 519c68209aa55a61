"""After Blender quit during training (train_quit.py): Train Avatar on the same frames,
tracking and Output with Resume ticked goes on from the saved step, as the quit message said;
with a Time limit of LIMIT minutes it ends by itself, its 20,000 steps cut to fit.

    blender --python train_resume.py -- SUBJECT_DIR CONFIG.json OUT_DIR STEP_AT_QUIT
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, script_args  # noqa: E402

SUBJECT, CONFIG, RUN = (Path(p) for p in script_args()[:3])
STEP_AT_QUIT = int(script_args()[3])
LIMIT = 0.25  # minutes from the backend's start, loading included


def resume(ui):
    from archhead_blender.training import current_run

    ui.op("archhead.import_sequence", filepath=str(SUBJECT / "tracking.npz"))
    run = ui_steps.start_training(ui, SUBJECT, CONFIG, RUN, resume=True, minutes=LIMIT)
    yield from ui.wait_until(lambda: run.status.total > 0, 20, "the resumed run to start")
    first = run.status.step
    ui.data["first_step"] = first
    check(first >= STEP_AT_QUIT, f"resumed at step {first}, quit at {STEP_AT_QUIT}")
    yield from ui.wait_until(
        lambda: current_run() is None, 60 * LIMIT + 10, "the time-limited run to end by itself"
    )
    ui.data["steps"] = run.status.step
    check(run.status.error is None, f"the run failed: {run.status.error}")
    check(run.status.step == run.status.total, f"ended at {run.status.step} of {run.status.total}")
    check(run.status.total < 20_000, f"{run.status.total} steps: the limit cut none")


run_steps([("Train Avatar with Resume", resume)])
