"""Training end to end on a tiny synthetic subject: the loss falls, the checkpoint decodes and
renders in the numpy runtime; the two stages; exact resume, and the state's checksum (a
changed value refused, a state without one resumed with a warning); the config file and CLI errors;
the per-frame refinement of the tracked codes (lr.codes, train/refine.py), its exact resume
and the refined tracking that `evaluate` scores training frames with."""

import dataclasses
import json
import re

import numpy as np
import pytest
import torch
from synthetic_models import random_model
from training_subject import TINY_CONFIG, write_config

from archhead_addon.avatar.runtime import AvatarRuntime
from archhead_addon.evaluate.__main__ import main as evaluate_main
from archhead_addon.evaluate.lods import cut_to_region
from archhead_addon.evaluate.render import render_frame
from archhead_addon.flame.model import load_model
from archhead_addon.io.errors import InputError, InputWarning
from archhead_addon.sequences import read_sequence
from archhead_addon.train.__main__ import main
from archhead_addon.train.config import TrainConfig
from archhead_addon.train.dataset import FrameDataset
from archhead_addon.train.loop import Trainer, frames_on_device, load_state
from archhead_addon.train.refine import REFINED
from archhead_addon.train.run_folder import RunFolder

CODES_LR = 0.01  # lr.codes of the refinement tests


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.fixture(scope="module")
def dataset(tiny_subject, model):
    return FrameDataset(tiny_subject, TINY_CONFIG["resolution"], model, split="train")


def trainer(dataset, model, out, **changes) -> Trainer:
    config = TrainConfig.from_dict({**TINY_CONFIG, **changes})
    frames = frames_on_device(dataset, torch.device("cpu"))
    return Trainer.create(
        config,
        frames,
        model,
        dataset.sequence.shape[0],
        out,
        dataset.background,
        torch.device("cpu"),
        sequence=dataset.sequence,
    )


def test_tiny_run_learns_and_its_checkpoint_renders_in_numpy(
    tiny_subject, dataset, tmp_path, capsys
):
    out = tmp_path / "run"
    rc = main(
        [
            "--data",
            str(tiny_subject),
            "--out",
            str(out),
            "--config",
            str(write_config(tmp_path / "tiny.json")),
            "--progress-json",
        ]
    )
    assert rc == 0
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert events[0]["event"] == "start" and events[0]["renderer"] == "cpu"
    assert events[-1]["event"] == "done" and events[-1]["step"] == 32
    steps = [e for e in events if e["event"] == "step"]
    assert [e["step"] for e in steps] == list(range(1, 33))
    assert {"stage", "step", "total", "loss", "seconds_per_step", "eta_seconds"} <= set(steps[0])
    assert steps[-1]["eta_seconds"] == 0 and steps[0]["eta_seconds"] > 0
    assert [e["step"] for e in events if e["event"] == "checkpoint"] == list(range(4, 33, 4))
    stage1 = [e["loss"]["rgb"] for e in steps if e["stage"] == 1]
    assert len(stage1) == 24 and np.mean(stage1[-4:]) < 0.7 * np.mean(stage1[:4])
    assert all(e["lods"] == [0.0] for e in steps if e["stage"] == 1)
    # stage 2, two levels: one in each half
    assert all([int(2 * lod) for lod in e["lods"]] == [0, 1] for e in steps[24:])
    assert ("lpips" in steps[0]["loss"]) and ("lpips" not in steps[1]["loss"])  # every 2nd

    runtime = AvatarRuntime.load(RunFolder(out).avatar)
    item = dataset[0]
    frames = {
        lod: render_frame(
            runtime, lod, item["codes"], item["K"], item["w2c"], dataset.size, dataset.background
        )
        for lod in (0.0, 1.0)
    }
    assert frames[0.0].gaussians > frames[1.0].gaussians > 0
    for frame in frames.values():
        assert np.isfinite(frame.rgb).all()
        error = torch.nn.functional.huber_loss(
            torch.from_numpy(frame.rgb), torch.from_numpy(item["image"]), delta=0.1
        )
        assert float(error) < 0.8 * np.mean(stage1[:4])  # the trained avatar, not the first


def test_stage_two_freezes_the_mapping_network(dataset, model, tmp_path):
    t = trainer(dataset, model, tmp_path, stage1_steps=1, stage2_steps=2)
    t.train_step()
    mapping = [p.detach().clone() for p in t.avatar.mapping.parameters()]
    decoder = [p.detach().clone() for p in t.avatar.decoder.parameters()]
    features = [p.detach().clone() for p in t.avatar.features.parameters()]
    t.train_step()
    t.train_step()
    assert all(
        torch.equal(a, b) for a, b in zip(mapping, t.avatar.mapping.parameters(), strict=True)
    )
    assert not all(
        torch.equal(a, b) for a, b in zip(decoder, t.avatar.decoder.parameters(), strict=True)
    )
    assert not all(
        torch.equal(a, b) for a, b in zip(features, t.avatar.features.parameters(), strict=True)
    )


def test_stages_three_and_four_train_the_feature_field_alone(dataset, model, tmp_path):
    """Stage 3: every feature level, at stage 2's draws; stage 4: the sparsest level alone,
    near LOD 1; both at the rate stage 2 ended on, the decoder, the mapping network and the
    codes' refinement fixed."""
    t = trainer(
        dataset, model, tmp_path, stage1_steps=1, stage2_steps=1, stage3_steps=2,
        stage4_steps=3, lod1_band=0.1, lods_per_step=1,
        lr={**TINY_CONFIG["lr"], "codes": CODES_LR},
    )  # fmt: skip
    cfg = t.config
    assert cfg.total_steps == 7 and [cfg.stage(s) for s in range(8)] == [1, 2, 3, 3, 4, 4, 4, 4]
    assert t.sparsest == "8"
    final = TINY_CONFIG.get("lr_final_ratio", 0.1)
    assert all(t.learning_rate_factor(s) == pytest.approx(final) for s in (2, 3, 6))
    near_1 = [t.lods(s) for s in range(4, 7)]
    assert all(len(x) == 1 and 0.9 <= x[0] <= 1.0 for x in near_1)
    assert len(set(map(tuple, near_1))) == 3
    assert not all(0.9 <= t.lods(s)[0] for s in range(2, 4))  # stage 2's draw: anywhere
    t.train_step()
    t.train_step()
    parts = {"mapping": t.avatar.mapping, "decoder": t.avatar.decoder, "codes": t.refinement}
    parts = {k: list(m.parameters()) for k, m in parts.items()}
    parts |= {f"features {s}": [level] for s, level in t.avatar.features.items()}

    def changed_by(steps: int) -> set[str]:
        before = {k: [p.detach().clone() for p in ps] for k, ps in parts.items()}
        reports = [t.train_step() for _ in range(steps)]
        assert len({r.stage for r in reports}) == 1
        return {
            k for k, ps in parts.items()
            if not all(torch.equal(a, b) for a, b in zip(before[k], ps, strict=True))
        }  # fmt: skip

    assert t.eta() > 0
    assert changed_by(2) == {"features 32", "features 16", "features 8"}  # stage 3
    assert changed_by(3) == {"features 8"}  # stage 4
    assert t.eta() == 0
    for key in ("stage3_steps", "stage4_steps"):
        with pytest.raises(InputError, match=key):
            TrainConfig.from_dict({key: 10, "avatar": {"levels": []}})
        with pytest.raises(InputError, match=key):
            TrainConfig.from_dict({key: -1})


def test_schedule_lods_frames_and_learning_rate(dataset, model, tmp_path):
    t = trainer(dataset, model, tmp_path, stage1_steps=4, stage2_steps=100, lods_per_step=5)
    assert t.lods(3) == [0.0]
    for step in (4, 50, 103):
        lods = t.lods(step)
        assert [int(5 * lod) for lod in lods] == [0, 1, 2, 3, 4]  # one level per fifth
        assert lods == t.lods(step)  # a function of the step
    assert len({tuple(t.lods(step)) for step in range(4, 104)}) == 100
    n = len(dataset)
    assert sorted(t.frame_index(s) for s in range(n)) == list(range(n))  # an epoch
    final = TINY_CONFIG.get("lr_final_ratio", 0.1)
    assert t.learning_rate_factor(0) == 1.0 == t.learning_rate_factor(4)  # each stage restarts
    assert t.learning_rate_factor(2) == pytest.approx(final**0.5)
    assert t.learning_rate_factor(104) == pytest.approx(final)
    one = trainer(dataset, model, tmp_path, stage1_steps=0, stage2_steps=10, lods_per_step=1)
    assert len({len(one.lods(s)) for s in range(10)}) == 1
    assert len({one.lods(s)[0] for s in range(10)}) == 10


def test_lod1_share_trains_the_sparsest_level_exactly(dataset, model, tmp_path):
    """With `lod1_share` q, about q of the stage-2 steps put their last level at LOD 1
    exactly (or, with `lod1_band` w, in [1 - w, 1], denser toward 1) and leave the others as
    they were; 0 is the plain stratified draw."""
    plain = trainer(dataset, model, tmp_path, stage1_steps=0, stage2_steps=400, lods_per_step=3)
    share = trainer(
        dataset, model, tmp_path, stage1_steps=0, stage2_steps=400, lods_per_step=3,
        lod1_share=0.25,
    )  # fmt: skip
    ends = 0
    for step in range(400):
        a, b = plain.lods(step), share.lods(step)
        assert a[:2] == b[:2] and b[2] in (a[2], 1.0)
        ends += b[2] == 1.0
    assert 70 <= ends <= 130  # 100 expected
    assert not any(lod == 1.0 for step in range(400) for lod in plain.lods(step))
    band = trainer(
        dataset, model, tmp_path, stage1_steps=0, stage2_steps=400, lods_per_step=3,
        lod1_share=1.0, lod1_band=0.1,
    )  # fmt: skip
    ends = [band.lods(step)[2] for step in range(400)]
    assert all(0.9 < lod <= 1.0 for lod in ends)
    assert sum(lod > 0.975 for lod in ends) > 0.4 * 400  # denser toward 1: half of them
    assert all(band.lods(step)[:2] == plain.lods(step)[:2] for step in range(400))
    for key in ("lod1_share", "lod1_band"):
        for bad in (-0.1, 1.5, float("nan")):
            with pytest.raises(ValueError, match=key):
                TrainConfig.from_dict({key: bad})


def test_a_cut_run_renders_the_background_outside_the_frames_region(dataset, model, tmp_path):
    plain = trainer(dataset, model, tmp_path / "plain")
    cut = trainer(dataset, model, tmp_path / "cut", cut="region")
    frame = cut.frames[0]
    h = frame.region.shape[0] // 2
    region = torch.ones_like(frame.region)
    region[:h] = 0
    frame = dataclasses.replace(frame, region=region)
    with torch.no_grad():
        drawn, cut_render = plain.render(frame, 0.0)[0], cut.render(frame, 0.0)[0]
    background = torch.as_tensor(dataset.background)
    assert torch.equal(cut_render[:h], background.expand(h, *cut_render.shape[1:2], 3))
    assert not torch.allclose(drawn[:h], cut_render[:h])  # the head reaches the cut half
    torch.testing.assert_close(cut_render[h:], drawn[h:])
    scored = cut_to_region(drawn.numpy(), region[..., 0].numpy(), dataset.background)
    np.testing.assert_allclose(scored, cut_render.numpy(), atol=1e-6)  # as `evaluate --cut`
    with pytest.raises(InputError, match="cut"):
        TrainConfig(cut="torso")


def test_a_frames_pose_is_computed_once_and_renders_as_its_codes(dataset, model, tmp_path):
    """The trainer keeps FLAME posed by each frame's own codes; what it draws is what the
    avatar draws from the codes, and the gradients reach the same parameters."""
    t = trainer(dataset, model, tmp_path)
    frame = t.frames[1]
    calls = []
    pose = t.avatar.pose
    t.avatar.pose = lambda *codes: calls.append(1) or pose(*codes)
    for _ in range(2):
        kept, g = t.render(frame, 0.3)
        assert g.means.requires_grad
    assert len(calls) == 1
    with torch.no_grad():
        plain = t.render(frame, 0.3, codes=frame.codes)[0]  # codes given: posed each time
    torch.testing.assert_close(kept.detach(), plain, atol=0, rtol=0)
    twin = dataclasses.replace(frame)  # another frame object: its own pose, never another's
    t.render(twin, 0.3)
    assert len(calls) == 3


def test_perceptual_term_schedules_stay_unbiased(dataset, model, tmp_path):
    """Every k-th step weighted k; with "one" level, one render of a stage-2 step in turn,
    weighted by the step's count of renders: over any k * n steps each render's term has
    the same total weight as on every render of every step."""
    every = trainer(dataset, model, tmp_path, lpips_every=2, lods_per_step=3)
    assert every.lpips_weights(0, 3) == [0.1] * 3 and every.lpips_weights(1, 3) == [0.0] * 3
    one = trainer(dataset, model, tmp_path, lpips_every=2, lpips_levels="one")
    weights = np.array([one.lpips_weights(step, 3) for step in range(6)])
    np.testing.assert_allclose(weights[::2], 0.3 * np.eye(3))
    assert not weights[1::2].any()
    assert one.lpips_weights(0, 1) == [0.1]  # stage 1: the one render
    with pytest.raises(ValueError, match="lpips_levels"):
        TrainConfig.from_dict({"lpips_levels": "some"})


def test_resumed_run_takes_the_same_steps(dataset, model, tmp_path):
    changes = {"stage1_steps": 3, "stage2_steps": 3, "checkpoint_every": 100}
    straight = trainer(dataset, model, tmp_path / "a", **changes)
    for _ in range(6):
        straight.train_step()

    first = trainer(dataset, model, tmp_path / "b", **changes)
    for _ in range(4):
        first.train_step()
    first.save()
    state = load_state(RunFolder(tmp_path / "b").state)
    assert state["step"] == 4
    frames = frames_on_device(dataset, torch.device("cpu"))
    resumed = Trainer.resume(
        state, tmp_path / "b", frames, model, dataset.background, torch.device("cpu")
    )
    resumed.train_step()
    resumed.train_step()
    for (name, a), b in zip(
        straight.avatar.state_dict().items(), resumed.avatar.state_dict().values(), strict=True
    ):
        assert torch.equal(a, b), name

    other = random_model()  # resuming with another FLAME model is refused by name
    with pytest.raises(
        ValueError,
        match=f"started on the FLAME model '{model.model_id}', resumed with '{other.model_id}'",
    ):
        Trainer.resume(
            state, tmp_path / "b", frames, other, dataset.background, torch.device("cpu")
        )


def test_a_state_with_one_changed_value_is_refused_by_its_checksum(dataset, model, tmp_path):
    run = trainer(dataset, model, tmp_path)
    run.train_step()
    run.save()
    path = RunFolder(tmp_path).state
    state = torch.load(path, weights_only=True)
    weight = next(v for k, v in state["model"].items() if k.startswith("decoder.")).view(-1)
    weight[0] = torch.nextafter(weight[0], weight[0] + 1)  # one plausible bit, no check sees it
    torch.save(state, path)
    with pytest.raises(InputError, match="does not match the file's content") as error:
        load_state(path)
    assert error.value.path == path and error.value.key == "checksum"
    assert str(error.value).startswith(f"{path}: ") and "damaged or was edited" in str(error.value)


def test_a_state_from_before_checksums_resumes_with_a_warning(dataset, model, tmp_path):
    run = trainer(dataset, model, tmp_path)
    run.train_step()
    run.save()
    path = RunFolder(tmp_path).state
    state = torch.load(path, weights_only=True)
    del state["checksum"]
    torch.save(state, path)
    with pytest.warns(InputWarning, match=re.escape(f"{path}: carries no checksum")):
        state = load_state(path)
    frames = frames_on_device(dataset, torch.device("cpu"))
    resumed = Trainer.resume(
        state, tmp_path, frames, model, dataset.background, torch.device("cpu")
    )
    resumed.train_step()
    assert resumed.step == 2


def test_presets_load_and_bad_configs_are_named(tmp_path):
    cpu, gpu = TrainConfig.load("cpu"), TrainConfig.load("gpu_paper")
    assert gpu.lods_per_step == 5 and (gpu.stage1_steps, gpu.stage2_steps) == (15000, 30000)
    assert gpu.avatar_config(100).levels == (256, 128, 64)
    assert (gpu.loss.parts, gpu.loss.lpips, gpu.loss.offset, gpu.loss.scale) == (
        20.0,
        0.05,
        0.001,
        0.5,
    )
    assert cpu.resolution == 256 and cpu.device == "auto"
    assert TrainConfig.from_dict(json.loads(cpu.to_json())) == cpu
    for bad, message in (
        ({"stage1_step": 3}, "stage1_step"),
        ({"loss": {"lpip": 1}}, "lpip"),
        ({"avatar": {"s_maxx": 3}}, "s_maxx"),
        ({"avatar": {"s_min": 300}}, "s_min"),
        ({"resolution": 16}, "32"),
    ):
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=message):
            TrainConfig.load(path)


def test_cli_refuses_to_overwrite_or_resume_nothing(tiny_subject, tmp_path, capsys):
    config = str(write_config(tmp_path / "tiny.json"))
    out = tmp_path / "run"
    assert main(["--data", str(tiny_subject), "--out", str(out), "--resume"]) == 2
    assert "nothing to resume" in capsys.readouterr().err
    RunFolder(out).state.parent.mkdir(parents=True)
    RunFolder(out).state.write_bytes(b"")
    assert main(["--data", str(tiny_subject), "--out", str(out), "--config", config]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["--data", str(tiny_subject), "--out", str(out), "--resume"]) == 2
    assert "unreadable training state" in capsys.readouterr().err
    assert (
        main(
            [
                "--data",
                str(tmp_path / "nowhere"),
                "--out",
                str(tmp_path / "r2"),
                "--config",
                config,
                "--progress-json",
            ]
        )
        == 2
    )
    error = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert error["event"] == "error" and "nowhere" in error["message"]


def test_cli_holdout_is_kept_in_the_run_s_config(tiny_subject, tmp_path, capsys):
    """--holdout interleaved trains without frame 4 of 8 and says so in config.json, which the
    evaluation reads back."""
    config = str(write_config(tmp_path / "tiny.json", stage1_steps=2, stage2_steps=1))
    out = tmp_path / "run"
    args = ["--data", str(tiny_subject), "--out", str(out), "--config", config]
    assert main([*args, "--holdout", "interleaved", "--progress-json"]) == 0
    assert json.loads(RunFolder(out).config.read_text())["holdout"] == "interleaved"
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    start = next(e for e in events if e["event"] == "start")
    assert start["frames"] == 7


def test_refinement_trains_resumes_exactly_and_writes_the_refined_tracking(
    dataset, model, tmp_path
):
    changes = {"stage1_steps": 4, "stage2_steps": 2, "checkpoint_every": 100}
    changes["lr"] = {**TINY_CONFIG["lr"], "codes": CODES_LR}
    straight = trainer(dataset, model, tmp_path / "a", **changes)
    for _ in range(6):
        straight.train_step()
    moved = straight.refinement.mean_size()
    assert set(moved) == set(REFINED) and all(v > 0 for v in moved.values())

    first = trainer(dataset, model, tmp_path / "b", **changes)
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
    assert main(args) == 0
    assert RunFolder(run).tracking.is_file()
    out = tmp_path / "eval"
    args = ["--avatar", str(run / "avatar.npz"), "--data", str(tiny_subject), "--out", str(out)]
    assert evaluate_main([*args, "--split", "train", "--lods", "0", "--precisions", "fp32"]) == 0
    assert "the run's refined tracking (tracking_refined.npz)" in capsys.readouterr().err
