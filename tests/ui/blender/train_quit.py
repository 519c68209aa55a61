"""Quit Blender while it trains: the backend saves a checkpoint and exits before Blender
does (the pytest side reads the run's log and finds no process left).

    blender --python train_quit.py -- SUBJECT_DIR CONFIG.json OUT_DIR
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import run_steps, script_args  # noqa: E402

SUBJECT, CONFIG, RUN = (Path(p) for p in script_args()[:3])


def start_training(ui):
    ui.op("archhead.import_sequence", filepath=str(SUBJECT / "tracking.npz"))
    run = ui_steps.start_training(ui, SUBJECT, CONFIG, RUN)
    yield from ui.wait_until(lambda: run.status.step >= 3, 30, "three training steps")
    yield from ui.show_sidebar()
    ui.screenshot("training_before_quit")


run_steps([("start training, then quit", start_training)])  # run_steps quits at the end
