"""The demo end to end at tiny sizes: synthetic subject, training by the project's command,
import, decode, contact sheet, LOD driver on a dolly-in camera, clip, .blend."""

import json
import subprocess
import sys

from PIL import Image
from training_subject import REPO_ROOT, write_config


def test_demo_trains_renders_and_saves(tmp_path):
    out = tmp_path / "demo"
    config = write_config(tmp_path / "tiny.json")
    command = [
        sys.executable,
        "-m",
        "archhead_addon",
        "demo",
        "--out",
        str(out),
        "--frames",
        "4",
        "--size",
        "64",
        "--subject-frames",
        "6",
        "--subject-size",
        "48",
        "--subject-samples",
        "4",
        "--train-config",
        str(config),
    ]
    # twice into the same folder, as `make demo` twice would: the second run trains anew
    for _ in range(2):
        done = subprocess.run(command, cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
        assert "demo done in" in done.stdout

    summary = json.loads((out / "demo_summary.json").read_text())
    assert (out / "demo.blend").stat().st_size > 0
    assert (out / "train" / "avatar.npz").is_file()
    assert summary["checkpoint"] == str(out / "train" / "avatar.npz")
    clip = sorted((out / "clip").glob("frame_*.png"))
    assert len(clip) == summary["frames"] == summary["decoded"] == 4
    gif = Image.open(out / "clip.gif")
    assert gif.n_frames == 4
    # the dolly starts beyond the driver's far distance and ends inside its near one
    assert summary["driven_lod"] == {"first frame": 1.0, "last frame": 0.0}
    counts = [count for _, _, count in summary["sheet_levels"]]
    assert all(a > b for a, b in zip(counts, counts[1:], strict=False))
    sheet = Image.open(out / "contact_sheet.png")
    assert sheet.width % len(counts) == 0 and sheet.height > 26
    assert all(t >= 0 for t in summary["seconds"].values())
