"""The probe (train/probe.py) on a tiny run: widened heads decode the same Gaussians, a probe
trains at its levels and leaves the run's files alone, bad input is named."""

import json

import pytest
import torch
from training_subject import write_config

from archhead_addon.flame.model import load_model
from archhead_addon.train.__main__ import main as train_main
from archhead_addon.train.dataset import FrameDataset
from archhead_addon.train.loop import Trainer, frames_on_device, load_state
from archhead_addon.train.probe import main as probe_main
from archhead_addon.train.probe import widen
from archhead_addon.train.run_folder import RunFolder


@pytest.fixture(scope="module")
def run(tiny_subject, tmp_path_factory):
    folder = tmp_path_factory.mktemp("probe")
    config = write_config(folder / "tiny.json")
    assert (
        train_main(
            ["--data", str(tiny_subject), "--out", str(folder / "run"), "--config", str(config)]
        )
        == 0
    )
    return folder / "run"


def test_widened_heads_decode_the_same_gaussians(tiny_subject, run):
    model = load_model()
    state = load_state(RunFolder(run).state)
    dataset = FrameDataset(tiny_subject, 48, model, split="train")
    frames = frames_on_device(dataset, torch.device("cpu"))
    narrow = Trainer.resume(
        state, run, frames, model, dataset.background, torch.device("cpu")
    ).avatar
    wide = widen(narrow, 24, 40)
    assert (wide.config.hidden, wide.config.colour_hidden) == (24, 40)
    assert sum(p.numel() for p in wide.parameters()) > sum(p.numel() for p in narrow.parameters())
    with torch.no_grad():
        for lod in (0.0, 0.6, 1.0):
            a, b = narrow(lod, **frames[1].codes), wide(lod, **frames[1].codes)
            for name in ("means", "log_scales", "quats", "opacity_logits", "sh"):
                torch.testing.assert_close(getattr(b, name), getattr(a, name), atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="cannot narrow"):
        widen(narrow, 8, 16)


def test_probe_trains_its_levels_and_leaves_the_run_alone(tiny_subject, run, capsys):
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    rc = probe_main(
        [
            "--run",
            str(run),
            "--data",
            str(tiny_subject),
            "--levels",
            "1",
            "--frame",
            "0",
            "--steps",
            "80",
            "--every",
            "40",
            "--no-regularisers",
        ]
    )
    assert rc == 0
    lines = capsys.readouterr().out.splitlines()
    assert "levels [1.0], 80 steps, 1 training frame(s), lr x 1.0, no regularisers" in lines[0]
    rows = [json.loads(line) for line in lines[1:]]
    assert [r["step"] for r in rows] == [0, 40, 80]
    assert set(rows[0]) == {"step", "seconds", "train l=0", "train l=1", "test l=0", "test l=1"}
    # one frame at one level, nothing but the image terms: its PSNR there must climb
    # (14.7 -> 16.1-16.2 dB; after 40 steps round-off alone moved it between 14.8 and 15.6)
    assert rows[-1]["train l=1"] > rows[0]["train l=1"] + 0.8
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before


def test_probe_names_bad_input(tiny_subject, run, tmp_path, capsys):
    assert probe_main(["--run", str(tmp_path), "--data", str(tiny_subject), "--steps", "0"]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path) in err and RunFolder(tmp_path).state.name in err
    assert (
        probe_main(
            ["--run", str(run), "--data", str(tiny_subject), "--steps", "0", "--frame", "99"]
        )
        == 2
    )
    assert "--frame 99: the run has 7 training frames" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        probe_main(["--run", str(run), "--data", str(tiny_subject), "--levels", "1.5"])
