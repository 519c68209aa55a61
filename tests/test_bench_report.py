"""The error-against-run-time report on a tiny subject and a tiny avatar: a row per LOD with
finite numbers, counts falling with the level, smoothness, ratios, stability, Blender's
update times, ablations trained with a tiny budget, the figures copied to --docs."""

import re
from itertools import takewhile

import numpy as np
import torch
from training_subject import SIZE, TINY_CONFIG, write_config

from archhead_addon.avatar.checkpoint import save_avatar
from archhead_addon.avatar.config import AvatarConfig
from archhead_addon.avatar.model import ArchHeadAvatar
from archhead_addon.flame.model import load_model
from archhead_addon.train.config import TrainConfig
from benchmarks.error_vs_time.__main__ import DOCS_REPORT, FIGURES, main
from benchmarks.error_vs_time.ablations import VARIANTS, variant_config


def _table(text: str, header: str) -> list[list[str]]:
    """The rows (cells) of the Markdown table whose header line starts with `header`."""
    lines = takewhile(lambda line: line.startswith("|"), text[text.index(header) :].splitlines())
    return [[c.strip() for c in line.strip("|").split("|")] for line in list(lines)[2:]]


def test_variant_config_keeps_the_budget_and_replaces_the_levels():
    base = TrainConfig.from_dict(TINY_CONFIG)
    for levels in VARIANTS.values():
        config = TrainConfig.from_dict(variant_config(base, levels, 12))
        assert config.total_steps == 12 and config.stage1_steps == 9  # 24 : 8 of the base
        assert config.avatar_config(1).levels == (
            base.avatar_config(1).levels if levels is None else tuple(levels)
        )
    staged = TrainConfig.from_dict({**TINY_CONFIG, "stage3_steps": 4, "stage4_steps": 4})
    for levels in VARIANTS.values():  # 24 : 8 : 4 : 4 of 40
        config = TrainConfig.from_dict(variant_config(staged, levels, 20))
        later = (0, 0) if levels == [] else (2, 2)  # no feature field for stages 3 and 4
        assert config.stage_steps == (12, 8 - sum(later), *later)


def test_report_has_a_finite_row_per_lod(tiny_subject, tmp_path, capsys):
    torch.manual_seed(0)
    config = AvatarConfig(
        s_max=32,
        s_min=8,
        levels=(32, 16, 8),
        feature_dim=8,
        hidden=16,
        colour_hidden=16,
        mapping_hidden=16,
    )
    avatar = tmp_path / "avatar.npz"
    save_avatar(avatar, ArchHeadAvatar.create(load_model(), config=config))
    out, docs = tmp_path / "report", tmp_path / "docs"
    assert (
        main(
            [
                "--avatar",
                str(avatar),
                "--data",
                str(tiny_subject),
                "--out",
                str(out),
                "--docs",
                str(docs),
                "--resolution",
                str(SIZE),
                "--step",
                "0.25",
                "--repeats",
                "1",
                "--ablations",
                "--steps",
                "2",
                "--ablation-config",
                str(write_config(tmp_path / "tiny.json")),
            ]
        )
        == 0
    )
    assert "report:" in capsys.readouterr().out
    text = (out / "report.md").read_text()
    assert (docs / DOCS_REPORT).read_text() == text
    for name in FIGURES:
        assert (out / name).stat().st_size > 0 and (docs / name).is_file()

    rows = _table(text, "| l | S | Gaussians")
    assert [float(r[0]) for r in rows] == [0.0, 0.25, 0.5, 0.75, 1.0]
    counts = [int(r[2].replace(",", "")) for r in rows]
    assert all(a > b for a, b in zip(counts, counts[1:], strict=False))
    numbers = np.array([[float(c) for c in r[4:]] for r in rows])  # timings and errors
    assert np.isfinite(numbers).all() and (numbers[:, :5] > 0).all()  # incl. Blender update

    assert len(_table(text, "| from l | to l |")) == 4
    assert re.search(r"Largest jump: l = \d\.\d\d -> \d\.\d\d", text)
    assert len(_table(text, "| LOD 1 vs LOD 0 (fp32) |")) == 6
    stability = _table(text, "| case |")
    assert len(stability) > 20 and all(r[4] == "0" for r in stability)  # no NaN / Inf
    ablations = _table(text, "| variant |")
    assert [r[0] for r in ablations] == [name for name in VARIANTS for _ in range(3)]
    assert np.isfinite([[float(c) for c in r[2:6]] for r in ablations]).all()
