"""Quit Blender while it trains: the backend saves a checkpoint and exits before Blender
does (the pytest side reads the run's log and finds no process left).

    blender --python train_quit.py -- SUBJECT_DIR CONFIG.json OUT_DIR
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ui_driver import check, run_steps, script_args  # noqa: E402

SUBJECT, CONFIG, RUN = (Path(p) for p in script_args()[:3])


def start_training(ui):
    from archhead_blender.training import current_run

    ui.op("archhead.import_sequence", filepath=str(SUBJECT / "tracking.npz"))
    ui.op(
        "archhead.train_avatar",
        frames_dir=str(SUBJECT / "frames"),
        tracking=str(SUBJECT / "tracking.npz"),
        out_dir=str(RUN),
        base_config=str(CONFIG),
    )
    run = current_run()
    check(run is not None, "no training run")
    ui.data["backend_pid"] = run.backend.process.pid
    yield from ui.wait_until(lambda: run.status.step >= 3, 240, "three training steps")
    yield from ui.show_sidebar()
    ui.screenshot("training_before_quit")


run_steps([("start training, then quit", start_training)])  # run_steps quits at the end
