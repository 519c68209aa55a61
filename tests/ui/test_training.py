"""Train Avatar in the window on a tiny subject rendered by the binary itself
(`blender -b --python scripts/synthetic_subject.py`), with progress and Cancel."""

import re
import shutil

import pytest

pytestmark = pytest.mark.ui


@pytest.fixture(scope="module")
def tiny_subject(blender_session):
    from ui_session import OUT, REPO

    folder = OUT / "data" / "tiny_subject"
    if not (folder / "tracking.npz").exists():
        blender_session.batch(
            [
                "--python",
                str(REPO / "scripts" / "synthetic_subject.py"),
                "--",
                *("--out", str(folder), "--frames", "8", "--size", "48", "--samples", "4"),
            ],
            OUT / "data",
            "synthetic_subject",
        )
    return folder


def test_train_progress_cancel_and_undo(blender_session, tiny_subject, cancelled_config):
    from ui_session import OUT

    out = OUT / "training"
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    result = blender_session.ui(
        "train_workflow.py", out, str(tiny_subject), str(cancelled_config), str(out / "run")
    )
    assert result["data"]["gaussians"] > 0
    assert (out / "run" / "train.log").is_file()


def test_quitting_during_training_saves_a_checkpoint_and_says_how_to_resume(
    blender_session, tiny_subject, cancelled_config
):
    from ui_session import OUT

    out = OUT / "training_quit"
    if out.exists():
        shutil.rmtree(out)
    run = out / "run"
    blender_session.ui("train_quit.py", out, str(tiny_subject), str(cancelled_config), str(run))
    log = (run / "train.log").read_text()
    assert '"event": "interrupted"' in log and "[exit code 130]" in log, log[-2000:]
    assert (run / "avatar.npz").is_file()
    # what the artist is told (Blender's console and the run's log): where it stopped, how
    # to go on
    said = re.search(r"ArchHead: training stopped at step (\d+) of \d+; .* Resume ticked", log)
    assert said, log[-2000:]
    assert said.group(0) in (out / "train_quit.log").read_text()
    step = int(said.group(1))
    assert step > 0
    # ... and doing so goes on from there
    resumed = blender_session.ui(
        "train_resume.py", out, str(tiny_subject), str(cancelled_config), str(run), str(step)
    )
    assert resumed["data"]["first_step"] >= step
    # with a Time limit the resumed run ended by itself, done, its steps fitted to the limit
    log = (run / "train.log").read_text()
    assert '"event": "done"' in log and "time limit:" in log, log[-2000:]
    assert step <= resumed["data"]["steps"] < 20_000
    starts = re.findall(r'"event": "start", "step": (\d+)', log)
    assert [int(s) for s in starts] == [0, step]  # the second run began where the first saved
