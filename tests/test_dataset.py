"""The training frame dataset: layout, resizing with K, background, parts mask B, split, and
one clear error per kind of bad input."""

import dataclasses
import re
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from archhead_addon.camera import project
from archhead_addon.flame import load_model
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.model import PART_OTHER
from archhead_addon.io.errors import InputError, InputWarning
from archhead_addon.sequences import write_canonical
from archhead_addon.sequences.demo import demo_sequence
from archhead_addon.train.config import TrainConfig
from archhead_addon.train.dataset import FrameDataset, split_indices, split_point, target_size
from archhead_addon.train.images import resize
from archhead_addon.train.parts_mask import parts_mask, rasterize

CODES = ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")


@pytest.fixture(scope="module")
def model():
    return load_model()


def posed(model, seq, t):
    return forward(model, **{k: getattr(seq, k)[t] for k in CODES})[0]


def blob(size, centre, sigma=2.5):
    """A Gaussian spot (H,W) at `centre` (x, y) in pixel coordinates, centres at +0.5."""
    rows, cols = np.indices(size) + 0.5
    return np.exp(-((cols - centre[0]) ** 2 + (rows - centre[1]) ** 2) / (2 * sigma**2))


def write_png(path, pixels):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.round(np.clip(pixels, 0, 1) * 255).astype(np.uint8)).save(path)


def make_data(root, model, frames=6, size=(60, 80), masks=False, seq=None):
    """DATA with tracking.npz and frames showing a spot at the projected head centre."""
    seq = seq or demo_sequence(frames, image_size=size)
    write_canonical(seq, root / "tracking.npz")
    for t in range(len(seq)):
        centre = project(posed(model, seq, t).mean(0, keepdims=True), seq.K[t], seq.w2c[t])[0]
        write_png(root / "frames" / f"{t:05d}.png", np.repeat(blob(size, centre)[..., None], 3, 2))
        if masks:
            write_png(root / "masks" / f"{t:05d}.png", np.ones(size))
    return seq


def centroid(image):
    rows, cols = np.indices(image.shape) + 0.5
    return np.array([(cols * image).sum(), (rows * image).sum()]) / image.sum()


def test_split_point_is_first_ninety_percent():
    assert [split_point(n) for n in (1, 2, 6, 10, 11, 300)] == [1, 1, 5, 9, 9, 270]
    assert split_indices(11) == (list(range(9)), [9, 10])


def test_interleaved_holdout_tests_every_tenth_frame():
    train, test = split_indices(35, "interleaved")
    assert test == [4, 14, 24, 34] and len(train) == 31 and not set(train) & set(test)
    assert split_indices(8, "interleaved") == ([0, 1, 2, 3, 5, 6, 7], [4])
    assert split_indices(4, "interleaved") == split_indices(4)  # too short to interleave
    with pytest.raises(ValueError, match="holdout"):
        split_indices(20, "random")
    with pytest.raises(ValueError, match="holdout"):
        TrainConfig(holdout="first")


def test_target_size():
    assert target_size(40, (60, 80)) == (30, 40)
    assert target_size(100, (81, 40)) == (100, 49)
    assert target_size((24, 32), (60, 80)) == (24, 32)
    with pytest.raises(ValueError):
        target_size(0, (60, 80))


def test_split_and_codes_follow_frame_order(tmp_path, model):
    seq = make_data(tmp_path, model, frames=10)
    train = FrameDataset(tmp_path, 40, model)
    test = FrameDataset(tmp_path, 40, model, split="test")
    assert (
        len(train) == 9
        and len(test) == 1
        and len(FrameDataset(tmp_path, 40, model, split="all")) == 10
    )
    np.testing.assert_array_equal(train.frame_ids, np.arange(9))
    item = test[0]
    assert item["index"] == 9 and item["frame_id"] == 9
    for k in CODES:
        np.testing.assert_allclose(item["codes"][k], getattr(seq, k)[9], rtol=1e-6, atol=1e-7)
        assert item["codes"][k].dtype == np.float32
    np.testing.assert_allclose(item["w2c"], seq.w2c[9], atol=1e-6)
    assert item["image"].shape == (30, 40, 3) and item["image"].dtype == np.float32
    assert item["mask"].shape == item["parts"].shape == (30, 40)
    assert (item["mask"] == 1).all()  # no masks: all foreground
    with pytest.raises(IndexError):
        test[1]
    moved = tmp_path / "elsewhere" / "seq.npz"
    moved.parent.mkdir()
    (tmp_path / "tracking.npz").rename(moved)
    assert len(FrameDataset(tmp_path, 40, model, tracking=moved)) == 9


@pytest.mark.parametrize("resolution", [40, (24, 50), 120])
def test_resized_frames_project_with_the_scaled_camera(tmp_path, model, resolution):
    """The spot drawn at the head centre's projection stays at its projection under K'
    (shrinking, anisotropic with non-integer factors, enlarging)."""
    seq = make_data(tmp_path, model, frames=3, size=(60, 80))
    data = FrameDataset(tmp_path, resolution, model, split="all")
    for t in range(3):
        item = data[t]
        expected = project(posed(model, seq, t).mean(0, keepdims=True), item["K"], item["w2c"])[0]
        spot = item["image"][..., 0]
        assert np.abs(centroid(spot) - expected).max() < 0.05
        np.testing.assert_allclose(
            item["K"][[0, 1], [0, 1]],
            seq.K[t][[0, 1], [0, 1]] * [data.size[1] / 80, data.size[0] / 60],
            rtol=1e-6,
        )


def test_tracked_at_another_size_scales_from_that_size(tmp_path, model):
    seq = make_data(tmp_path, model, frames=2, size=(60, 80))
    tracked = dataclasses.replace(
        seq, K=seq.K * np.array([2, 2, 1])[:, None], image_size=(120, 160)
    )  # tracked on 2x frames
    write_canonical(tracked, tmp_path / "tracking.npz")
    data = FrameDataset(tmp_path, 40, model, split="all")
    np.testing.assert_allclose(data[0]["K"], seq.K[0] * np.array([0.5, 0.5, 1])[:, None], rtol=1e-6)


def test_masks_composite_over_the_background(tmp_path, model):
    seq = demo_sequence(2, image_size=(20, 20))
    write_canonical(seq, tmp_path / "tracking.npz")
    colour = np.array([0.2, 0.4, 0.6])
    alpha = np.zeros((20, 20))
    alpha[:, :10] = 1
    for t in range(2):
        write_png(tmp_path / "frames" / f"{t:05d}.png", np.broadcast_to(colour, (20, 20, 3)))
        write_png(tmp_path / "masks" / f"{t:05d}.png", alpha)
    data = FrameDataset(tmp_path, 20, model, split="all", background=(1.0, 0.0, 0.0))
    image = data[0]["image"]
    assert data.has_masks
    np.testing.assert_allclose(image[:, :10], np.broadcast_to(colour, (20, 10, 3)), atol=1 / 255)
    np.testing.assert_allclose(image[:, 10:], np.broadcast_to([1, 0, 0], (20, 10, 3)))
    np.testing.assert_array_equal(data[0]["mask"], alpha)


def test_frame_alpha_is_the_mask_without_masks_folder(tmp_path, model):
    write_canonical(demo_sequence(2, image_size=(8, 8)), tmp_path / "tracking.npz")
    rgba = np.zeros((8, 8, 4))
    rgba[..., 1] = 1.0
    rgba[:4, :, 3] = 1.0
    for t in range(2):
        write_png(tmp_path / "frames" / f"{t:05d}.png", rgba)
    item = FrameDataset(tmp_path, 8, model, split="all", background=(0, 0, 1))[1]
    np.testing.assert_array_equal(item["image"][:4], np.broadcast_to([0, 1, 0], (4, 8, 3)))
    np.testing.assert_array_equal(item["image"][4:], np.broadcast_to([0, 0, 1], (4, 8, 3)))


def test_exr_frames_are_srgb_encoded(tmp_path, model):
    write_canonical(demo_sequence(2, image_size=(6, 8)), tmp_path / "tracking.npz")
    linear = np.zeros((6, 8, 3), np.float32)
    linear[..., 0], linear[..., 1], linear[..., 2] = 0.214041, 1.0, 4.0  # 4.0: over-bright
    (tmp_path / "frames").mkdir()
    for t in range(2):
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with OpenEXR.File(header, {"RGB": linear}) as f:
            f.write(str(tmp_path / "frames" / f"{t:05d}.exr"))
    image = FrameDataset(tmp_path, 8, model, split="all")[0]["image"]
    np.testing.assert_allclose(image[0, 0], [0.5, 1.0, 1.0], atol=1e-4)


def test_given_parts_masks_are_used(tmp_path, model):
    make_data(tmp_path, model, frames=2, size=(60, 80))
    parts = np.zeros((60, 80))
    parts[10:30, 20:60] = 1
    for t in range(2):
        write_png(tmp_path / "parts" / f"{t:05d}.png", parts)
    halved = FrameDataset(tmp_path, 40, model, split="all")[0]["parts"]
    expected = np.zeros((30, 40))
    expected[5:15, 10:30] = 1
    np.testing.assert_allclose(halved, expected, atol=1e-6)  # 2x2 averages
    data = FrameDataset(tmp_path, 30, model, split="all")  # factors 60/22 and 8/3
    area = (data.size[0] / 60) * (data.size[1] / 80)
    np.testing.assert_allclose(data[0]["parts"].sum(), parts.sum() * area, rtol=1e-5)


def test_generated_parts_cover_visible_eyes_and_mouth(model):
    seq = demo_sequence(1, image_size=(128, 128))
    verts = posed(model, seq, 0)
    b = parts_mask(model, verts, seq.K[0], seq.w2c[0], (128, 128))
    faces_at, _ = rasterize(verts, model.faces, seq.K[0], seq.w2c[0], (128, 128))
    assert 0.005 < b.mean() < 0.1 and (faces_at[b > 0] >= 0).all()
    pupil = np.argmax(np.where(model.weights[:, 3] == 1, verts[:, 2], -np.inf))  # left eye front
    x, y = project(verts[pupil][None], seq.K[0], seq.w2c[0])[0]
    assert b[int(y), int(x)] == 1


def test_model_without_part_labels_warns_and_gives_empty_parts(tmp_path, model):
    make_data(tmp_path, model, frames=2)
    with pytest.warns(InputWarning, match="no eye/mouth labels"):
        data = FrameDataset(tmp_path, 32, model.replace(vertex_parts=None), split="all")
    assert data[0]["parts"].shape == data.size and data[0]["parts"].max() == 0


def test_generated_parts_respect_occlusion(model):
    """Seen from behind, every eye and mouth vertex projects into the image, yet none is
    visible: B is empty (splatting vertex labels would not be)."""
    seq = demo_sequence(1, image_size=(96, 96))
    behind = dataclasses.replace(seq, rotation=np.array([[0.0, np.pi, 0.0]]))
    verts = posed(model, behind, 0)
    labelled = verts[model.vertex_parts != PART_OTHER]
    xy = project(labelled, behind.K[0], behind.w2c[0])
    assert ((xy >= 0) & (xy < 96)).all()
    assert parts_mask(model, verts, behind.K[0], behind.w2c[0], (96, 96)).sum() == 0


def test_rasterizer_depth_order_and_pixel_centres():
    """Two squares at depths 2 and 1 under an identity camera; pixel (i, j) is covered when
    its centre (j + 0.5, i + 0.5) is inside."""
    K, w2c = np.eye(3), np.eye(4)

    def square(x0, y0, x1, y1, z):  # given in pixels, placed at depth z
        return np.array([[x0, y0, 1], [x1, y0, 1], [x1, y1, 1], [x0, y1, 1]]) * z

    points = np.concatenate([square(0, 0, 6, 6, 2.0), square(2.6, 2.6, 8, 8, 1.0)])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    face_at, bary = rasterize(points, faces, K, w2c, (8, 8))
    far = np.isin(face_at, [0, 1])
    near = np.isin(face_at, [2, 3])
    expected_near = np.zeros((8, 8), bool)
    expected_near[3:, 3:] = True  # centres from 3.5 on lie past 2.6
    np.testing.assert_array_equal(near, expected_near)
    np.testing.assert_array_equal(far, (np.indices((8, 8)) < 6).all(0) & ~expected_near)
    np.testing.assert_allclose(bary[face_at >= 0].sum(-1), 1.0)


def test_importing_the_dataset_loads_no_torch():
    code = (
        "import sys, archhead_addon.train.dataset, archhead_addon.train; "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# ---------------------------------------------------------------- bad input


def _raises(path, problem, *args, **kwargs):
    with pytest.raises(InputError, match="^" + re.escape(f"{path}: ") + problem):
        FrameDataset(*args, **kwargs)


def test_missing_frames_are_named(tmp_path, model):
    make_data(tmp_path, model, frames=6)
    (tmp_path / "frames" / "00003.png").unlink()
    _raises(
        tmp_path / "frames",
        r"5 frames for 6 tracked frames .*missing frame numbers 3$",
        tmp_path,
        32,
        model,
    )


def test_more_frames_than_tracking(tmp_path, model):
    make_data(tmp_path, model, frames=4)
    write_canonical(demo_sequence(3, image_size=(60, 80)), tmp_path / "tracking.npz")
    _raises(
        tmp_path / "frames",
        r"4 frames but the tracking .* has only 3: frames 00003.png",
        tmp_path,
        32,
        model,
    )


def test_frames_of_another_size(tmp_path, model):
    make_data(tmp_path, model, frames=4)
    write_png(tmp_path / "frames" / "00002.png", np.zeros((60, 81)))
    _raises(
        tmp_path / "frames" / "00002.png",
        r"81x60 pixels, but 00000.png is 80x60",
        tmp_path,
        32,
        model,
    )


def test_unreadable_frame(tmp_path, model):
    make_data(tmp_path, model, frames=4)
    (tmp_path / "frames" / "00001.png").write_bytes(b"not a png")
    _raises(tmp_path / "frames" / "00001.png", "unreadable image", tmp_path, 32, model)


def test_truncated_frame_fails_when_loaded(tmp_path, model):
    make_data(tmp_path, model, frames=4)
    path = tmp_path / "frames" / "00001.png"
    path.write_bytes(path.read_bytes()[:80])  # the header survives, the pixels do not
    data = FrameDataset(tmp_path, 32, model)
    with pytest.raises(InputError, match="^" + re.escape(f"{path}: unreadable image")):
        data[1]


def test_mask_missing_or_of_another_size(tmp_path, model):
    make_data(tmp_path, model, frames=4, masks=True)
    write_png(tmp_path / "masks" / "00002.png", np.ones((30, 40)))
    _raises(
        tmp_path / "masks" / "00002.png",
        r"40x30 pixels, but the frames are 80x60",
        tmp_path,
        32,
        model,
    )
    (tmp_path / "masks" / "00002.png").unlink()
    _raises(tmp_path / "masks", r"no mask for frames 00002.png", tmp_path, 32, model)


def test_mixed_image_types(tmp_path, model):
    make_data(tmp_path, model, frames=3)
    Image.open(tmp_path / "frames" / "00002.png").convert("RGB").save(
        tmp_path / "frames" / "00002.jpg"
    )
    (tmp_path / "frames" / "00002.png").unlink()
    _raises(tmp_path / "frames", r"mixed image types \(.jpg, .png\)", tmp_path, 32, model)


def test_tracking_missing_or_without_camera(tmp_path, model):
    seq = make_data(tmp_path, model, frames=3)
    write_canonical(dataclasses.replace(seq, K=None, w2c=None), tmp_path / "tracking.npz")
    _raises(tmp_path / "tracking.npz", "key 'K': the tracking has no camera", tmp_path, 32, model)
    (tmp_path / "tracking.npz").unlink()
    _raises(tmp_path, "no tracking.npz in this folder", tmp_path, 32, model)
    _raises(tmp_path / "nowhere", "data folder not found", tmp_path / "nowhere", 32, model)


def test_tracking_camera_of_another_aspect(tmp_path, model):
    seq = make_data(tmp_path, model, frames=3, size=(60, 80))
    write_canonical(dataclasses.replace(seq, image_size=(80, 80)), tmp_path / "tracking.npz")
    _raises(
        tmp_path / "frames",
        "frames are 80x60 pixels but the tracking's camera is for 80x80",
        tmp_path,
        32,
        model,
    )


def test_single_frame_has_no_test_split(tmp_path, model):
    make_data(tmp_path, model, frames=1)
    assert len(FrameDataset(tmp_path, 32, model)) == 1
    _raises(tmp_path, "the 'test' split of 1 frame", tmp_path, 32, model, split="test")


def test_renumbered_frames_warn(tmp_path, model):
    make_data(tmp_path, model, frames=3)
    (tmp_path / "frames" / "00002.png").rename(tmp_path / "frames" / "00007.png")
    with pytest.warns(InputWarning, match="matched to tracked frames by order"):
        FrameDataset(tmp_path, 32, model, split="all")


def _axis_weights(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) in float64, pixel i covering [i, i + 1): shrinking, the overlap of each
    output pixel's span with each input pixel over its width; enlarging, bilinear between
    the input centres around the output centre, clamped at the edges."""
    if n_out <= n_in:
        span = n_in / n_out
        lo, hi = np.arange(n_out)[:, None] * span, (np.arange(n_out)[:, None] + 1) * span
        k = np.arange(n_in)[None]
        return np.clip(np.minimum(hi, k + 1) - np.maximum(lo, k), 0, None) / span
    x = np.clip((np.arange(n_out) + 0.5) * n_in / n_out - 0.5, 0, n_in - 1)
    weights = np.zeros((n_out, n_in))
    for j, xj in enumerate(x):
        k0 = min(int(np.floor(xj)), max(n_in - 2, 0))
        weights[j, k0] += 1 - (xj - k0)
        if n_in > 1:
            weights[j, k0 + 1] += xj - k0
    return weights


@pytest.mark.parametrize(
    "shape, size",
    [
        ((1080, 1080, 3), (512, 512)),  # a full-HD crop to the tracker's frames: area
        ((340, 340, 3), (512, 512)),  # a small crop enlarged: bilinear
        ((512, 512), (256, 256)),  # a mask to the training size
        ((360, 640, 3), (100, 713)),  # one axis shrinks, the other grows, factors not whole
        ((7, 1, 3), (3, 5)),  # a one-pixel axis enlarged holds its value
        ((9, 9), (9, 4)),  # one axis kept
    ],
)
def test_resize_is_the_area_mean_shrinking_and_bilinear_enlarging(shape, size):
    rng = np.random.default_rng(sum(shape))
    pixels = rng.integers(0, 256, shape).astype(np.uint8)
    out = resize(pixels, size)
    rows, cols = _axis_weights(shape[0], size[0]), _axis_weights(shape[1], size[1])
    planes = pixels.reshape(*shape[:2], -1).astype(np.float64)
    wanted = np.einsum("ih,hwc,jw->ijc", rows, planes, cols, optimize=True)
    wanted = wanted.reshape(*size, *shape[2:])
    assert out.dtype == np.float32 and out.shape == wanted.shape
    np.testing.assert_allclose(out, wanted, rtol=0, atol=2e-4)
    # a view, not contiguous (as the tracker's crops are): the flip of the flipped pixels
    np.testing.assert_allclose(resize(pixels[::-1], size), wanted[::-1], rtol=0, atol=2e-4)
