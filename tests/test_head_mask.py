"""The head without its neck, the tracker's head-and-neck mask, the masks a run trains on and
the metrics over the head."""

import os
import shutil

import numpy as np
import pytest
import torch
from PIL import Image
from test_dataset import CODES, make_data, posed, write_png

from archhead_addon.evaluate.metrics import psnr, ssim
from archhead_addon.flame import load_model
from archhead_addon.flame.regions import JAW_JOINT, NECK_JOINT, face_vertices, head_vertices
from archhead_addon.io.errors import InputError
from archhead_addon.sequences.demo import demo_sequence
from archhead_addon.track.head_mask import HAIR_REACH, head_and_neck_masks, region
from archhead_addon.train.config import TrainConfig
from archhead_addon.train.dataset import FrameDataset
from archhead_addon.train.images import resize
from archhead_addon.train.parts_mask import surface_regions


@pytest.fixture(scope="module")
def model():
    return load_model()


def test_the_head_keeps_face_chin_and_eyes_and_drops_the_lower_neck(model):
    head = head_vertices(model)
    v = model.v_template
    neck_y = (model.j_regressor @ v)[NECK_JOINT, 1]
    assert head[model.weights[:, 3] > 0.99].all()  # the eyeballs
    jaw = model.weights[:, JAW_JOINT] > 0.5
    assert head[jaw & (v[:, 2] > 0.06)].all()  # the chin, in front of the throat
    assert head[v[:, 1] > neck_y].all()  # everything above the base of the skull
    bottom = v[:, 1] < v[:, 1].min() + 0.03
    assert bottom.any() and not head[bottom].any()
    assert 0.05 < (~head).mean() < 0.4


def test_the_face_is_the_heads_front_below_the_forehead(model):
    """Eyes, nose tip, mouth and chin are in it; the ears, the back of the head and the
    crown are not."""
    face, head = face_vertices(model), head_vertices(model)
    v = model.v_template
    assert not (face & ~head).any()
    assert face[model.weights[:, 3] > 0.99].all()  # the eyeballs
    assert face[np.argmax(v[:, 2])]  # the nose tip, the most forward point
    jaw = model.weights[:, JAW_JOINT] > 0.5
    assert face[jaw & (v[:, 2] > 0.06)].all()  # the chin and the lower lip
    assert not face[v[:, 1] > v[:, 1].max() - 0.05].any()  # the crown
    assert not face[np.argmax(np.abs(v[:, 0]))]  # the widest point: an ear
    assert not face[head & (v[:, 2] < (model.j_regressor @ v)[NECK_JOINT, 2])].any()  # the back
    assert 0.3 < face.sum() / head.sum() < 0.8


def _frame(model, seq, t, size):
    """The frame's regions seen from twice as far (the demo's head fills its frame)."""
    K = seq.K[t] * [[0.5], [0.5], [1]]
    K[:2, 2] = np.array(size[::-1]) / 2
    return surface_regions(model, posed(model, seq, t), K, seq.w2c[t], size)


def test_regions_nest_and_the_mask_adds_hair_above_not_below(model):
    size = (96, 96)
    seq = demo_sequence(3, image_size=size)
    found = _frame(model, seq, 0, size)
    head, mesh = found.head > 0.5, found.mesh > 0.5
    assert head.any() and (mesh & ~head).any()
    assert not (head & ~mesh).any() and not (found.parts.astype(bool) & ~mesh).any()
    face = found.face > 0.5
    assert face.any() and (head & ~face).any() and not (face & ~head).any()
    inside = region(found.head, found.mesh)
    assert (inside | ~mesh).all()  # the whole mesh is kept
    rows = np.flatnonzero(head.any(axis=1))
    height = rows[-1] - rows[0] + 1
    above = rows[0] - int(0.8 * HAIR_REACH * height)
    assert above >= 0 and inside[above].any()  # hair above the crown
    mesh_bottom = np.flatnonzero(mesh.any(axis=1))[-1]
    assert not inside[mesh_bottom + 1 :].any()  # nothing below where the neck ends
    # beside the neck (shoulders) and below the chin, the region is only the neck's outline
    below = inside[rows[-1] + 1 : mesh_bottom + 1]
    widened = mesh[rows[-1] + 1 : mesh_bottom + 1]
    assert below.sum() < 1.5 * widened.sum()


def test_masks_follow_each_frame_of_the_fit(model):
    size = (64, 64)
    seq = demo_sequence(5, image_size=size)
    codes = {k: getattr(seq, k) for k in CODES}
    codes["shape"] = seq.shape[0]
    masks = list(head_and_neck_masks(model, codes, seq.K[0], seq.w2c[0], size, chunk=2))
    assert len(masks) == 5
    for t in (0, 4):
        found = surface_regions(model, posed(model, seq, t), seq.K[0], seq.w2c[0], size)
        np.testing.assert_array_equal(masks[t], region(found.head, found.mesh))


def test_runs_train_on_head_masks_or_the_whole_person(tmp_path, model):
    make_data(tmp_path, model, frames=6, masks=True)
    person = np.zeros((60, 80))
    person[10:50, 20:60] = 1
    for t in range(6):
        write_png(tmp_path / "masks_person" / f"{t:05d}.png", person)
    head = FrameDataset(tmp_path, 80, model, split="all", background=(0, 0, 0))
    whole = FrameDataset(tmp_path, 80, model, split="all", mask="person", background=(0, 0, 0))
    assert head[0]["mask"].min() == 1.0  # masks/ is all ones here
    np.testing.assert_allclose(whole[0]["mask"], person, atol=1 / 255)
    assert whole[0]["image"][:10].max() == 0.0
    assert head[0]["head"].shape == (60, 80) and head[0]["head"].any()
    # what the tracker's mask may keep, from the tracked mesh alone (a `cut` run's renders)
    found = surface_regions(
        model, posed(model, head.sequence, 0), head.K[0], head.sequence.w2c[0], (60, 80)
    )
    np.testing.assert_array_equal(head[0]["region"], region(found.head, found.mesh))
    assert 0 < head[0]["region"].mean() < 1
    # at a smaller training size: drawn at the frames' size, then resized as the masks are
    small = FrameDataset(tmp_path, 40, model, split="all", background=(0, 0, 0))
    wanted = resize(region(found.head, found.mesh).astype(np.float32), (30, 40))
    np.testing.assert_allclose(small[0]["region"], wanted, atol=1e-6)
    assert whole[0]["region"].min() == 1.0  # the whole person: nothing cut
    (tmp_path / "masks_person" / "00003.png").unlink()
    with pytest.raises(InputError, match="00003"):
        FrameDataset(tmp_path, 80, model, split="all", mask="person")
    with pytest.raises(ValueError, match="mask must be one of"):
        FrameDataset(tmp_path, 80, model, mask="hair")
    with pytest.raises(InputError, match="mask"):
        TrainConfig(mask="torso")


def test_a_person_run_needs_the_person_masks(tmp_path, model):
    make_data(tmp_path, model, frames=4, masks=True)
    with pytest.raises(InputError, match="masks_person"):
        FrameDataset(tmp_path, 80, model, mask="person")


def test_frames_picks_the_same_spread_frames_for_training_and_scoring(tmp_path, model):
    make_data(tmp_path, model, frames=30)
    one = FrameDataset(tmp_path, 40, model, split="train", holdout="interleaved", frames=1)
    ten = FrameDataset(tmp_path, 40, model, split="train", holdout="interleaved", frames=10)
    every = FrameDataset(tmp_path, 40, model, split="train", holdout="interleaved")
    assert len(one) == 1 and len(ten) == 10
    assert ten.indices[0] == every.indices[0] and ten.indices[-1] == every.indices[-1]
    assert set(ten.indices) <= set(every.indices)
    with pytest.raises(ValueError, match="frames"):
        FrameDataset(tmp_path, 40, model, frames=0)


def test_region_metrics_score_only_the_region():
    torch.manual_seed(0)
    truth = torch.rand(48, 48, 3)
    render = truth.clone()
    render[:, 24:] = 0  # wrong on the right half only
    left = torch.zeros(48, 48)
    left[:, :19] = 1  # windows centred here reach column 23 at most
    assert psnr(render, truth, left) == float("inf")
    assert psnr(render, truth) < 15
    assert ssim(render, truth, left) == pytest.approx(1.0)
    assert ssim(render, truth) < 0.8
    assert np.isnan(psnr(render, truth, torch.zeros(48, 48)))
    whole = torch.ones(48, 48)
    assert psnr(render, truth, whole) == pytest.approx(psnr(render, truth))
    assert ssim(render, truth, whole) == pytest.approx(ssim(render, truth))


def test_tracked_folders_hold_both_masks(tmp_path):
    """The tracker's output on the real clip's first frames (the real landmark model)."""
    from archhead_addon.track.pipeline import TrackOptions, track
    from archhead_addon.track.real_subject import REAL_VIDEO, fetch_media

    out = tmp_path / "tracked"
    track(fetch_media() / REAL_VIDEO, out, TrackOptions(size=96, max_frames=6, photometric=None))
    names = sorted(p.name for p in (out / "masks").iterdir())
    assert names == sorted(p.name for p in (out / "masks_person").iterdir()) and names
    assert names == sorted(p.name for p in (out / "regions").iterdir())
    for name in names:
        head = np.asarray(Image.open(out / "masks" / name), np.int32)
        person = np.asarray(Image.open(out / "masks_person" / name), np.int32)
        inside = np.asarray(Image.open(out / "regions" / name), np.int32)
        assert set(np.unique(inside)) == {0, 255}  # the region is hard, the person soft
        assert (head <= person + 1).all()  # head and neck lie within the person
        assert (head[inside == 0] == 0).all()  # ... and within the region
        assert head.sum() > 0.2 * person.sum()
        assert (head > 127).sum() < (person > 127).sum()  # shoulders and shirt left out
    data = FrameDataset(out, 96, load_model(), split="all")
    assert (data[0]["head"] <= (data[0]["mask"] > 0)).mean() > 0.95  # the face is kept
    # a `cut` run's region holds all the mask keeps, at any training size: cutting a render
    # there never removes what the truth shows
    for size in (96, 40):
        cut = FrameDataset(out, size, load_model(), split="all")
        assert cut.cuts_to_region
        for i in range(len(cut)):
            assert (cut[i]["mask"] <= cut[i]["region"] + 1e-5).all()
            assert cut[i]["region"].min() < 1
    # a folder tracked before regions/ existed: the region drawn from its tracking is the one
    # the tracker wrote
    written = FrameDataset(out, 40, load_model(), split="all")
    written = [written[i]["region"] for i in range(len(written))]
    shutil.rmtree(out / "regions")
    drawn = FrameDataset(out, 40, load_model(), split="all")
    assert drawn.cuts_to_region and drawn.region_paths is None
    for i in range(len(drawn)):
        np.testing.assert_allclose(drawn[i]["region"], written[i], atol=1e-6)


def test_a_killed_tracking_leaves_nothing_for_the_next_run(tmp_path):
    """A stage of a killed run (its process gone) is removed by the next run into the same
    folder, whatever its OUT; a live run's stage stays."""
    import subprocess
    import sys

    from archhead_addon.track.folder import OWNER_FILE, staged_folder

    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    dead = tmp_path / "first.partial-abc"
    dead.mkdir()
    (dead / OWNER_FILE).write_text(gone.stdout.strip())
    live = tmp_path / "other.partial-def"
    live.mkdir()
    (live / OWNER_FILE).write_text(str(os.getpid()))
    with staged_folder(tmp_path / "second") as stage:
        assert (stage / OWNER_FILE).read_text() == str(os.getpid())
    assert not dead.exists() and live.exists()
    assert (tmp_path / "second").is_dir() and not (tmp_path / "second" / OWNER_FILE).exists()
