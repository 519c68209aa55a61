"""Evaluation: the metrics on hand-made images, and the command line on a tiny subject
(tables, plot, LOD montage, cross-identity reenactment through the driver's own camera)."""

import csv
import json
import math
import shutil
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image
from training_subject import SIZE

from archhead_addon.avatar.checkpoint import save_avatar
from archhead_addon.avatar.config import AvatarConfig
from archhead_addon.avatar.model import ArchHeadAvatar
from archhead_addon.avatar.runtime import AvatarRuntime
from archhead_addon.evaluate.__main__ import main
from archhead_addon.evaluate.metrics import (
    SSIM_C1,
    SSIM_C2,
    gaussian_kernel,
    l1,
    psnr,
    ssim,
)
from archhead_addon.evaluate.render import render_frame
from archhead_addon.flame.model import load_model
from archhead_addon.sequences import read_sequence, write_canonical
from archhead_addon.train.dataset import FrameDataset


def test_l1_and_psnr_of_a_constant_offset():
    a = torch.zeros(8, 8, 3)
    assert l1(a + 0.1, a) == pytest.approx(0.1)
    assert psnr(a + 0.1, a) == pytest.approx(20.0)  # MSE 0.01
    assert psnr(a, a) == math.inf


def gaussian_window() -> np.ndarray:
    """SSIM's 11 x 11 window."""
    g = gaussian_kernel().numpy()
    return g[:, None] * g[None, :]


def test_gaussian_window_is_normalised_with_sigma_one_and_a_half():
    w = gaussian_window()
    assert w.shape == (11, 11) and w.sum() == pytest.approx(1.0)
    assert w[5, 5] / w[5, 6] == pytest.approx(math.exp(1 / (2 * 1.5**2)))  # sigma 1.5
    assert w[5, 5] / w[6, 6] == pytest.approx(math.exp(2 / (2 * 1.5**2)))  # separable
    assert np.array_equal(w, w.T)


def test_ssim_of_flat_images_is_the_luminance_term():
    a, b = torch.full((16, 16, 3), 0.2), torch.full((16, 16, 3), 0.6)
    assert ssim(a, b) == pytest.approx((2 * 0.2 * 0.6 + SSIM_C1) / (0.2**2 + 0.6**2 + SSIM_C1))
    assert ssim(a, a) == pytest.approx(1.0)


def test_ssim_of_one_window_by_hand():
    rng = np.random.default_rng(0)
    x, y = rng.random((11, 11, 1)), rng.random((11, 11, 1))
    w = gaussian_window()[..., None]
    mx, my = (w * x).sum(), (w * y).sum()
    vx, vy = (w * (x - mx) ** 2).sum(), (w * (y - my) ** 2).sum()
    cxy = (w * (x - mx) * (y - my)).sum()
    expected = (
        (2 * mx * my + SSIM_C1)
        * (2 * cxy + SSIM_C2)
        / ((mx**2 + my**2 + SSIM_C1) * (vx + vy + SSIM_C2))
    )
    assert ssim(torch.from_numpy(x), torch.from_numpy(y)) == pytest.approx(expected, rel=1e-9)
    noisy = torch.from_numpy(np.clip(x + 0.1 * rng.normal(size=x.shape), 0, 1))
    assert ssim(torch.from_numpy(x), noisy) == pytest.approx(ssim(noisy, torch.from_numpy(x)))
    with pytest.raises(ValueError, match="11"):
        ssim(torch.zeros(8, 8, 3), torch.zeros(8, 8, 3))


def test_ssim_averages_every_valid_window():
    """Against the 2-D window slid over the image (the separable blur is only a speed-up)."""
    rng = np.random.default_rng(1)
    x, y = rng.random((40, 37, 3)), rng.random((40, 37, 3))
    w = gaussian_window()

    def blur(a):  # (H, W, C) -> the valid windows' weighted sums
        windows = np.lib.stride_tricks.sliding_window_view(a, (11, 11), axis=(0, 1))
        return np.einsum("hwcij,ij->hwc", windows, w)

    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx**2, blur(y * y) - my**2, blur(x * y) - mx * my
    expected = (
        (2 * mx * my + SSIM_C1)
        * (2 * cxy + SSIM_C2)
        / ((mx**2 + my**2 + SSIM_C1) * (vx + vy + SSIM_C2))
    ).mean()
    assert ssim(torch.from_numpy(x), torch.from_numpy(y)) == pytest.approx(expected, rel=1e-12)


@pytest.fixture(scope="module")
def avatar_file(tmp_path_factory):
    """A small untrained avatar, with random feature maps (so every level differs)."""
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
    path = tmp_path_factory.mktemp("avatar") / "avatar.npz"
    save_avatar(path, ArchHeadAvatar.create(load_model(), config=config))
    return path


def test_evaluation_writes_tables_plot_and_images(tiny_subject, avatar_file, tmp_path, capsys):
    # the driver: the subject's own tracking, stored for images twice the size
    seq = read_sequence(tiny_subject / "tracking.npz")
    double = replace(seq, K=np.diag([2.0, 2.0, 1.0]) @ seq.K, image_size=(2 * SIZE, 2 * SIZE))
    write_canonical(double, tmp_path / "driver.npz")
    out = tmp_path / "eval"
    assert (
        main(
            [
                "--avatar",
                str(avatar_file),
                "--data",
                str(tiny_subject),
                "--out",
                str(out),
                "--resolution",
                str(SIZE),
                "--drive",
                str(tmp_path / "driver.npz"),
                "--drive-frames",
                "8",
            ]
        )
        == 0
    )
    assert "| LOD 1 vs LOD 0 (fp32) |" in capsys.readouterr().out

    rows = list(csv.DictReader((out / "metrics.csv").open()))
    assert [(float(r["lod"]), r["precision"]) for r in rows] == [
        (lod, p) for p in ("fp32", "fp16") for lod in (0.0, 0.25, 0.5, 0.75, 1.0)
    ]
    counts = [int(r["gaussians"]) for r in rows[:5]]
    assert counts == sorted(counts, reverse=True) and counts[-1] > 0
    for a, b in zip(rows[:5], rows[5:], strict=True):  # fp16 decodes almost alike
        assert int(a["gaussians"]) == int(b["gaussians"])
        assert abs(float(a["psnr"]) - float(b["psnr"])) < 0.05
    for r in rows:
        assert 0 < float(r["l1"]) < 1 and 0 < float(r["ssim"]) <= 1 and float(r["render_ms"]) > 0

    model = load_model()
    test = FrameDataset(tiny_subject, SIZE, model, split="test")
    item = test[0]
    image = render_frame(
        AvatarRuntime.load(avatar_file, model),
        0.0,
        item["codes"],
        item["K"],
        item["w2c"],
        test.size,
        test.background,
    ).rgb
    rows0 = rows[0]
    assert float(rows0["psnr"]) == pytest.approx(
        10 * math.log10(1 / np.mean((np.clip(image, 0, 1) - item["image"]) ** 2)), rel=1e-4
    )
    # the face PSNR (the one test frame) over the face's pixels only
    face = item["face"]
    assert len(test) == 1 and face.any() and (item["head"] > face).any()  # inside the head
    assert float(rows0["psnr_face"]) == pytest.approx(
        10 * math.log10(1 / np.mean(((np.clip(image, 0, 1) - item["image"])[face]) ** 2)),
        rel=1e-4,
    )

    montage = np.asarray(Image.open(out / "lods.png"))
    assert montage.shape == (SIZE, 6 * SIZE, 3)  # truth, then five levels
    sheet = np.asarray(Image.open(out / "sheet.png")).astype(np.float32) / 255
    assert sheet.shape == (len(test) * SIZE, 4 * SIZE, 3)  # test frames by truth, 0, 0.5, 1
    assert np.abs(sheet[:SIZE, :SIZE] - item["image"]).max() <= 1 / 255 + 1e-6
    assert np.abs(sheet[:SIZE, SIZE : 2 * SIZE] - np.clip(image, 0, 1)).max() <= 1 / 255 + 1e-6
    assert Image.open(out / "error_vs_time.png").size[0] > 500

    driven = sorted((out / "reenact").iterdir())
    assert len(driven) == 8
    # the last tracked frame is the test frame: the driver's camera, scaled back to 48 px,
    # must give the evaluation's own render of it
    last = np.asarray(Image.open(driven[-1]), np.float32) / 255
    assert np.abs(last - np.clip(image, 0, 1)).max() <= 1 / 255 + 1e-6


def test_bad_arguments_are_refused(tiny_subject, avatar_file, tmp_path, capsys):
    assert (
        main(["--avatar", str(avatar_file), "--data", str(tiny_subject), "--out", str(tmp_path)])
        == 2
    )  # no training config beside the avatar
    assert "--resolution" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(
            [
                "--avatar",
                str(avatar_file),
                "--data",
                str(tiny_subject),
                "--out",
                str(tmp_path),
                "--lods",
                "0,2",
            ]
        )


def test_training_frames_can_be_scored_evenly_spread(tiny_subject, avatar_file, tmp_path):
    out = tmp_path / "eval"
    args = ["--avatar", str(avatar_file), "--data", str(tiny_subject), "--out", str(out)]
    args += ["--resolution", str(SIZE), "--lods", "0", "--precisions", "fp32"]
    assert main([*args, "--split", "train", "--frames", "3"]) == 0
    assert "3 train frames" in (out / "metrics.md").read_text()
    model = load_model()
    train = FrameDataset(tiny_subject, SIZE, model, split="train")
    runtime = AvatarRuntime.load(avatar_file, model)
    spread = [0, (len(train) - 1) / 2, len(train) - 1]
    errors = []
    for i in spread:
        item = train[round(i)]
        rgb = render_frame(
            runtime, 0.0, item["codes"], item["K"], item["w2c"], train.size, train.background
        ).rgb
        errors.append(np.mean((np.clip(rgb, 0, 1) - item["image"]) ** 2))
    row = next(csv.DictReader((out / "metrics.csv").open()))
    expected = np.mean([10 * math.log10(1 / e) for e in errors])
    assert float(row["psnr"]) == pytest.approx(expected, rel=1e-4)


def test_the_run_s_holdout_picks_the_test_frames(tiny_subject, avatar_file, tmp_path):
    """A run trained with "holdout": "interleaved" is scored on every tenth frame, from the
    fifth: here frame 4 of 8, not the last."""
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(avatar_file, run / "avatar.npz")
    (run / "config.json").write_text(json.dumps({"resolution": SIZE, "holdout": "interleaved"}))
    out = tmp_path / "eval"
    args = ["--avatar", str(run / "avatar.npz"), "--data", str(tiny_subject), "--out", str(out)]
    assert main([*args, "--lods", "0", "--precisions", "fp32"]) == 0
    assert "1 test frames" in (out / "metrics.md").read_text()
    everything = FrameDataset(tiny_subject, SIZE, load_model(), split="all")
    truth = np.asarray(Image.open(out / "lods.png"))[:, :SIZE].astype(np.float32) / 255
    assert np.abs(truth - everything[4]["image"]).max() <= 1 / 255 + 1e-6
    assert np.abs(truth - everything[7]["image"]).max() > 0.05


def test_an_avatar_without_its_config_is_told_its_holdout(
    tiny_subject, avatar_file, tmp_path, capsys
):
    """Away from its run's config.json, --holdout picks the held-out frames (interleaved:
    frame 4 of 8); without it the last 10 % are scored and stderr says so."""
    out = tmp_path / "eval"
    args = ["--avatar", str(avatar_file), "--data", str(tiny_subject), "--out", str(out)]
    args += ["--resolution", str(SIZE), "--lods", "0", "--precisions", "fp32"]
    everything = FrameDataset(tiny_subject, SIZE, load_model(), split="all")

    def scored_truth():
        return np.asarray(Image.open(out / "lods.png"))[:, :SIZE].astype(np.float32) / 255

    assert main([*args, "--holdout", "interleaved"]) == 0
    assert np.abs(scored_truth() - everything[4]["image"]).max() <= 1 / 255 + 1e-6
    assert "scoring the last 10 %" not in capsys.readouterr().err
    assert main(args) == 0
    assert "--holdout interleaved" in capsys.readouterr().err
    assert np.abs(scored_truth() - everything[7]["image"]).max() <= 1 / 255 + 1e-6


def test_error_regions_split_the_error_over_head_mask_and_background(
    tiny_subject, avatar_file, tmp_path, repo_root
):
    """benchmarks/error_regions.py: its pixel shares are the dataset's head, the rest of the
    mask and the rest of the frame; the error shares add up to the whole."""
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(avatar_file, run / "avatar.npz")
    (run / "config.json").write_text(json.dumps({"resolution": SIZE, "holdout": "last"}))
    command = [sys.executable, "benchmarks/error_regions.py", "--avatar", str(run / "avatar.npz")]
    command += ["--data", str(tiny_subject), "--split", "train"]
    out = subprocess.run(command, cwd=repo_root, capture_output=True, text=True, check=True).stdout
    rows = [line.split("|")[1:4] for line in out.splitlines() if line.startswith("| the ")]
    rows += [line.split("|")[1:4] for line in out.splitlines() if line.startswith("| outside")]
    assert [name.strip() for name, _, _ in rows] == [
        "the head without its neck",
        "the rest of the mask",
        "outside the mask",
    ]
    error = [float(e.strip(" %")) for _, e, _ in rows]
    pixels = [float(p.strip(" %")) for _, _, p in rows]
    assert sum(error) == pytest.approx(100, abs=2) and min(error) >= 0
    train = FrameDataset(tiny_subject, SIZE, load_model(), split="train")
    head = np.mean([train[i]["head"] > 0.5 for i in range(len(train))])
    kept = np.mean([(train[i]["mask"] > 0.5) | (train[i]["head"] > 0.5) for i in range(len(train))])
    assert pixels[0] == pytest.approx(100 * head, abs=0.6)
    assert pixels[0] + pixels[1] == pytest.approx(100 * kept, abs=1.1)
    # renders cut to the tracking's region, as a `cut` run's: less is drawn past the mask
    # (the region is the tracker's: only its folders, which hold masks_person/, are cut)
    data = shutil.copytree(tiny_subject, tmp_path / "data")
    shutil.copytree(data / "masks", data / "masks_person")
    command[command.index(str(tiny_subject))] = str(data)
    command += ["--cut", "region"]
    out = subprocess.run(command, cwd=repo_root, capture_output=True, text=True, check=True).stdout
    outside = next(line for line in out.splitlines() if line.startswith("| outside"))
    assert float(outside.split("|")[2].strip(" %")) < error[2]


def test_levels_are_a_list_or_a_range():
    from archhead_addon.evaluate.__main__ import parse_args

    def lods(text):
        return parse_args(["--avatar", "a", "--data", "d", "--out", "o", "--lods", text]).lods

    assert lods("0,0.5,1") == [0.0, 0.5, 1.0]
    assert lods("0:1:0.05") == [round(0.05 * i, 6) for i in range(21)]
    for bad in ("0:2:0.5", "1:0:0.5", "0:1:0", "a:b:c", "0,1.5"):
        with pytest.raises(SystemExit):
            lods(bad)


def test_rods_and_needles_are_counted_apart():
    """A flat disc (two long axes) counts as a needle (axis ratio over 10) but not as a rod; a
    rod six times longer than wide draws a dash and is not a needle; a sphere is neither."""
    from types import SimpleNamespace

    from archhead_addon.evaluate.render import needle_share, rod_share

    sphere, disc, rod = [1e-3, 1e-3, 1e-3], [1e-4, 5e-3, 5e-3], [1e-3, 6e-3, 1e-3]
    g = SimpleNamespace(log_scales=np.log(np.array([sphere, disc, rod], np.float32)))
    assert needle_share(g) == pytest.approx(1 / 3) and rod_share(g) == pytest.approx(1 / 3)
    assert rod_share(SimpleNamespace(log_scales=np.log(np.array([disc, sphere])))) == 0
    assert rod_share(SimpleNamespace(log_scales=np.zeros((0, 3)))) == 0


def test_black_counts_colours_floored_in_every_channel():
    """A Gaussian is black when its floored colour is 0 in all three channels; one dark
    channel is a colour, not black."""
    from archhead_addon.evaluate.render import black_share

    colours = np.array([[0, 0, 0], [0, 0.2, 0], [0.5, 0.5, 0.5], [0, 0, 0]], np.float32)
    assert black_share(colours) == pytest.approx(0.5)
    assert black_share(np.zeros((0, 3), np.float32)) == 0
