"""Per-frame refinement of the tracked codes (lr.codes, train/refine.py): the deltas train with
the avatar, resume exactly, and each checkpoint writes the refined tracking beside the avatar,
changed on the training frames only; `evaluate` scores training frames with it."""

import numpy as np
import pytest
import torch
from training_subject import TINY_CONFIG, write_config

from archhead_addon.evaluate.__main__ import main as evaluate_main
from archhead_addon.flame.model import load_model
from archhead_addon.sequences import read_sequence
from archhead_addon.train.__main__ import main as train_main
from archhead_addon.train.config import TrainConfig
from archhead_addon.train.dataset import FrameDataset
from archhead_addon.train.loop import Trainer, frames_on_device, load_state
from archhead_addon.train.refine import REFINED
from archhead_addon.train.run_folder import RunFolder

CODES_LR = 0.01


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.fixture(scope="module")
def dataset(tiny_subject, model):
    return FrameDataset(tiny_subject, TINY_CONFIG["resolution"], model, split="train")


def make(dataset, model, out, **changes) -> Trainer:
    data = {**TINY_CONFIG, "lr": {**TINY_CONFIG["lr"], "codes": CODES_LR}, **changes}
    return Trainer.create(
        TrainConfig.from_dict(data),
        frames_on_device(dataset, torch.device("cpu")),
        model,
        dataset.sequence.shape[0],
        out,
        dataset.background,
        torch.device("cpu"),
        sequence=dataset.sequence,
    )


def test_refinement_trains_resumes_exactly_and_writes_the_refined_tracking(
    dataset, model, tmp_path
):
    changes = {"stage1_steps": 4, "stage2_steps": 2, "checkpoint_every": 100}
    straight = make(dataset, model, tmp_path / "a", **changes)
    for _ in range(6):
        straight.train_step()
    moved = straight.refinement.mean_size()
    assert set(moved) == set(REFINED) and all(v > 0 for v in moved.values())

    first = make(dataset, model, tmp_path / "b", **changes)
    for _ in range(4):
        first.train_step()
    first.save()
    state = load_state(RunFolder(tmp_path / "b").state)
    assert set(state["refinement"]) == set(REFINED)
    frames = frames_on_device(dataset, torch.device("cpu"))
    resumed = Trainer.resume(
        state, tmp_path / "b", frames, model, dataset.background, torch.device("cpu"),
        sequence=dataset.sequence,
    )  # fmt: skip
    resumed.train_step()
    resumed.train_step()
    for k, v in straight.refinement.state().items():
        assert torch.equal(v, resumed.refinement.state()[k]), k
    for (name, a), b in zip(
        straight.avatar.state_dict().items(), resumed.avatar.state_dict().values(), strict=True
    ):
        assert torch.equal(a, b), name

    resumed.save()
    refined = read_sequence(RunFolder(tmp_path / "b").tracking)
    tracked = dataset.sequence
    shown = [frames[resumed.frame_index(step)].index for step in range(6)]
    held_out = sorted(set(range(len(tracked))) - {f.index for f in frames})
    assert held_out, "the tiny subject holds frames out"
    for k in REFINED:
        delta = np.abs(getattr(refined, k) - getattr(tracked, k)).sum(axis=1)
        assert (delta[shown] > 0).all(), k  # every frame a step rendered moved
        assert (delta[held_out] == 0).all(), k  # held-out frames stay as tracked


def test_a_refined_run_is_scored_with_its_refined_codes(tiny_subject, tmp_path, capsys):
    config = write_config(
        tmp_path / "c.json",
        stage1_steps=6,
        stage2_steps=2,
        lr={**TINY_CONFIG["lr"], "codes": CODES_LR},
    )
    run = tmp_path / "run"
    args = ["--data", str(tiny_subject), "--out", str(run), "--config", str(config)]
    assert train_main(args) == 0
    assert RunFolder(run).tracking.is_file()
    out = tmp_path / "eval"
    args = ["--avatar", str(run / "avatar.npz"), "--data", str(tiny_subject), "--out", str(out)]
    assert evaluate_main([*args, "--split", "train", "--lods", "0", "--precisions", "fp32"]) == 0
    assert "the run's refined tracking (tracking_refined.npz)" in capsys.readouterr().err
