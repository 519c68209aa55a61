"""The synthetic subject: its trajectory, its output folder, and a tiny Cycles render whose
masks agree with the tracked camera projecting the exact mesh."""

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from archhead_addon.camera import project
from archhead_addon.flame import load_model
from archhead_addon.flame.builtin import EXPRESSION_NAMES
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.teeth import add_teeth
from archhead_addon.sequences import read_sequence
from archhead_addon.synthetic.png import encode_png
from archhead_addon.synthetic.subject import SubjectFolder
from archhead_addon.synthetic.trajectory import EXPRESSION_PEAKS, synthetic_sequence
from archhead_addon.train.dataset import FrameDataset
from archhead_addon.train.parts_mask import rasterize

REPO_ROOT = Path(__file__).resolve().parents[1]
SCRIPT = REPO_ROOT / "scripts" / "synthetic_subject.py"
CODES = ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")
FPS = 25.0


@pytest.fixture(scope="module")
def long_run():
    return synthetic_sequence(1500, 256, seed=3)


def vertices(model, seq):
    return forward(model, **{k: getattr(seq, k) for k in CODES})


def test_same_seed_same_motion_and_prefix_stable():
    a, b = synthetic_sequence(120, 64, seed=5), synthetic_sequence(120, 64, seed=5)
    assert a.data_equal(b)
    longer = synthetic_sequence(400, 64, seed=5)
    assert longer.subset(0, 120).data_equal(a)
    assert not synthetic_sequence(120, 64, seed=6).data_equal(a)


def test_head_turns_within_thirty_degrees_and_stays_in_frame(long_run):
    yaw = np.degrees(np.abs(long_run.neck[:, 1] + long_run.rotation[:, 1]))
    assert yaw.max() <= 30 and yaw.max() > 18  # turns, but never past 30 degrees
    model = load_model()
    face = model.v_template[:, 1] > -0.09  # everything above the neck
    verts = vertices(model, long_run.subset(0, None, 10))
    for t, v in enumerate(verts):
        xy = project(v[face], long_run.K[10 * t], long_run.w2c[10 * t])
        assert (xy > 2).all() and (xy < 254).all(), f"frame {10 * t} leaves the image"


def test_motion_is_smooth_and_varied(long_run):
    seq = long_run
    velocity = np.degrees(np.diff(seq.neck, axis=0))  # degrees per frame at 25 fps
    assert np.abs(velocity).max() < 2.5 and np.abs(np.diff(velocity, axis=0)).max() < 0.5
    jaw = seq.jaw[:, 0]
    assert jaw.min() >= 0 and 0.25 < jaw.max() <= 0.3 and 0.2 < (jaw > 0.05).mean() < 0.9
    np.testing.assert_allclose(seq.expr[:, EXPRESSION_NAMES.index("jaw_open")], 2.0 * jaw)
    for name in EXPRESSION_PEAKS:
        assert seq.expr[:, EXPRESSION_NAMES.index(name)].max() > 0.2, name
    blink = seq.expr[:, EXPRESSION_NAMES.index("blink_left")]
    closed = np.flatnonzero(np.diff((blink > 0.9).astype(int)) == 1)
    assert 10 < len(closed) < 45  # one every 1.5-5 s over 60 s
    spread = seq.expr[:, 10:].std(axis=0)
    assert spread[:10].mean() > 5 * spread[-10:].mean() > 0  # sizes decay with the index
    eyes = seq.eyes
    np.testing.assert_array_equal(eyes[:, :3], eyes[:, 3:])
    glance = np.abs(np.diff(eyes[:, 1]))
    assert glance.max() > 0.05 and np.abs(eyes[:, 1]).max() <= 0.35  # fast saccades, in range


def test_png_encoder_round_trips():
    rng = np.random.default_rng(0)
    for shape in ((5, 7), (5, 7, 3), (4, 3, 4)):
        pixels = rng.integers(0, 256, shape, dtype=np.uint8)
        decoded = np.asarray(Image.open(io.BytesIO(encode_png(pixels))))
        np.testing.assert_array_equal(decoded, pixels)
    with pytest.raises(ValueError):
        encode_png(np.zeros((4, 4), np.float32))


def test_folder_writes_frame_and_mask_and_clears_an_earlier_run(tmp_path):
    folder = SubjectFolder(tmp_path)
    folder.prepare()
    (folder.frames / "00007.png").write_bytes(b"stale")
    (folder.frames / "notes.txt").write_text("kept")
    folder.prepare()
    assert sorted(p.name for p in folder.frames.iterdir()) == ["notes.txt"]
    rgba = np.zeros((4, 6, 4), np.uint8)
    rgba[..., :3] = 77
    rgba[1:3, 2:5, 3] = 255
    folder.write_frame(0, rgba)
    frame = np.asarray(Image.open(folder.frames / "00000.png"))
    mask = np.asarray(Image.open(folder.masks / "00000.png"))
    np.testing.assert_array_equal(mask, rgba[..., 3])
    np.testing.assert_array_equal(frame, np.where(rgba[..., 3:] > 0, rgba[..., :3], 0))


def test_render_script_imports_only_bpy_and_numpy():
    """Blender's Python has numpy but neither torch nor Pillow."""
    pytest.importorskip("bpy")
    code = (
        "import sys; import archhead_blender.synthetic_subject; "
        "extra = {'torch', 'PIL', 'OpenEXR', 'scipy'} & set(sys.modules); "
        "assert not extra, extra"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """6 frames at 48x48, 2 samples, through the script as Blender would run it."""
    pytest.importorskip("bpy")
    out = tmp_path_factory.mktemp("subject")
    proc = subprocess.run(
        [
            sys.executable,
            str(SCRIPT),
            "--",
            "--out",
            str(out),
            "--frames",
            "6",
            "--size",
            "48",
            "--samples",
            "2",
            "--seed",
            "4",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out, proc.stdout


def test_render_writes_the_documented_layout(rendered):
    out, stdout = rendered
    names = [f"{t:05d}.png" for t in range(6)]
    assert sorted(p.name for p in (out / "frames").iterdir()) == names
    assert sorted(p.name for p in (out / "masks").iterdir()) == names
    assert "synthetic subject: 6 frames of 48x48 px, 2 samples" in stdout
    assert str(out / "tracking.npz") in stdout
    seq = read_sequence(out / "tracking.npz")
    assert seq.data_equal(synthetic_sequence(6, 48, seed=4))
    frame = Image.open(out / "frames" / "00000.png")
    mask = Image.open(out / "masks" / "00000.png")
    assert (frame.mode, frame.size, mask.mode, mask.size) == ("RGB", (48, 48), "L", (48, 48))


def test_masks_match_the_tracked_camera(rendered):
    """The rendered silhouette is the exact mesh seen through K, w2c: every vertex projects
    inside it, and it agrees with a z-buffer coverage of the mesh to a tenth of a pixel."""
    out, _ = rendered
    seq = read_sequence(out / "tracking.npz")
    model = add_teeth(load_model())
    for t, v in enumerate(vertices(model, seq)):
        alpha = np.asarray(Image.open(out / "masks" / f"{t:05d}.png")) / 255.0
        col, row = np.floor(project(v, seq.K[t], seq.w2c[t])).astype(int).T
        seen = (row >= 0) & (row < 48) & (col >= 0) & (col < 48)  # not the cut-off neck
        padded = np.pad(alpha, 1)
        near = np.max(
            [padded[1 + dr : 49 + dr, 1 + dc : 49 + dc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)],
            axis=0,
        )  # alpha within one pixel
        assert seen.mean() > 0.8 and near[row[seen], col[seen]].min() > 0
        assert (alpha[row[seen], col[seen]] > 0.5).mean() > 0.9  # rim vertices aside
        coverage = rasterize(v, model.faces, seq.K[t], seq.w2c[t], (48, 48))[0] >= 0
        assert np.abs(alpha - coverage).sum() < 0.06 * coverage.sum()  # edge pixels only
        rows, cols = np.indices(alpha.shape)
        for grid in (rows, cols):
            shift = (grid * alpha).sum() / alpha.sum() - grid[coverage].mean()
            assert abs(shift) < 0.1, f"frame {t}: silhouettes {shift:.3f} px apart"


def test_rendered_subject_reads_as_a_dataset(rendered):
    out, _ = rendered
    model = add_teeth(load_model())
    train = FrameDataset(out, 32, model)
    test = FrameDataset(out, 32, model, split="test", background=(0.0, 0.0, 0.0))
    assert len(train) == 5 and len(test) == 1 and train.size == (32, 32)
    item = train[0]
    assert 0 < item["parts"].sum() and (item["mask"][item["parts"] > 0] > 0.5).all()
    face = item["mask"] > 0.99
    assert item["image"][face].mean() > 0.2  # a lit head, not black
    np.testing.assert_allclose(item["image"][item["mask"] == 0], 1.0)  # white background
    assert np.abs(test[0]["image"][test[0]["mask"] == 0]).max() == 0
