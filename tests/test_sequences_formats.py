"""Each reader on files written in that format's real layout (keys, shapes, dtypes, cameras).

The writers below follow the public code of each project: VHAP's export_as_nerf_dataset and
tracker.save_result, metrical-tracker's Tracker.save_checkpoint, flame-head-tracker's
tracker_base.run_fitting / tracker_video (see the reader modules' docstrings).
"""

import json
import pickle
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch

from archhead_addon.io.errors import InputWarning
from archhead_addon.rotations import axis_angle_to_matrix
from archhead_addon.sequences import (
    Sequence,
    detect_format,
    read_canonical,
    read_sequence,
    write_canonical,
)

F32 = np.float32


def look_at_c2w_gl(eye, target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)):
    """Camera-to-world in OpenGL camera axes (x right, y up, looking down -z)."""
    eye = np.asarray(eye, dtype=np.float64)
    z = eye - np.asarray(target)
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, np.cross(z, x), z, eye
    return c2w


def project(seq: Sequence, t: int, points):
    """Pixel coordinates of world points through the sequence's K and w2c."""
    cam = (seq.w2c[t] @ np.c_[points, np.ones(len(points))].T)[:3]
    uvw = seq.K[t] @ cam
    return (uvw[:2] / uvw[2]).T


def points(rng, n=20):
    return rng.uniform(-0.1, 0.1, size=(n, 3))


# ---------------------------------------------------------------- VHAP / GaussianAvatars


def vhap_codes(rng, n, n_verts=40):
    return {
        "translation": rng.normal(0, 0.01, (n, 3)).astype(F32),
        "rotation": rng.normal(0, 0.2, (n, 3)).astype(F32),
        "neck_pose": rng.normal(0, 0.1, (n, 3)).astype(F32),
        "jaw_pose": rng.normal(0, 0.1, (n, 3)).astype(F32),
        "eyes_pose": rng.normal(0, 0.1, (n, 6)).astype(F32),
        "shape": rng.normal(0, 1, 300).astype(F32),
        "expr": rng.normal(0, 1, (n, 100)).astype(F32),
        "static_offset": rng.normal(0, 1e-3, (1, n_verts, 3)).astype(F32),
    }


def write_vhap_export(root, timesteps=(0, 1, 2, 3), cameras=(0,), seed=0, split=None):
    """An export_as_nerf_dataset folder: flame_param/<t>.npz plus transforms.json."""
    rng = np.random.default_rng(seed)
    codes = vhap_codes(rng, len(timesteps))
    (root / "flame_param").mkdir(parents=True)
    frames, cams = [], {}
    for c in cameras:
        eye = np.r_[rng.uniform(-0.5, 0.5, 2), 1.0 + rng.uniform(0, 0.3)]
        cams[c] = {
            "c2w": look_at_c2w_gl(eye),
            "fl_x": 1000.0 + 10 * c,
            "fl_y": 1002.0 + 10 * c,
            "cx": 251.5 + c,
            "cy": 262.25,
            "w": 512,
            "h": 520,
        }
    for i, t in enumerate(timesteps):
        per_t = {k: v if k in ("shape", "static_offset") else v[[i]] for k, v in codes.items()}
        per_t["dynamic_offset"] = np.zeros((1, 40, 3), F32)
        np.savez(root / "flame_param" / f"{t:05d}.npz", **per_t)
        for c in cameras:
            cam = cams[c]
            frames.append(
                {
                    "timestep_index": t,
                    "timestep_index_original": t,
                    "timestep_id": f"frame_{t:05d}",
                    "camera_index": c,
                    "camera_id": f"22{c:04d}",
                    "cx": cam["cx"],
                    "cy": cam["cy"],
                    "fl_x": cam["fl_x"],
                    "fl_y": cam["fl_y"],
                    "h": cam["h"],
                    "w": cam["w"],
                    "camera_angle_x": 0.5,
                    "camera_angle_y": 0.5,
                    "transform_matrix": cam["c2w"].tolist(),
                    "file_path": f"images/{t:05d}_{c:02d}.png",
                    "fg_mask_path": f"fg_masks/{t:05d}_{c:02d}.png",
                    "flame_param_path": f"flame_param/{t:05d}.npz",
                }
            )
    db = {
        "frames": frames,
        "cx": 256.0,
        "cy": 256.0,
        "fl_x": 1000.0,
        "fl_y": 1000.0,
        "h": 520,
        "w": 512,
        "timestep_indices": list(timesteps),
        "camera_indices": list(cameras),
    }
    if split is None:
        (root / "transforms.json").write_text(json.dumps(db))
    else:  # GaussianAvatars' division: the last timestep is the test split
        test = [f for f in frames if f["timestep_index"] == timesteps[-1]]
        for name, part in (("train", [f for f in frames if f not in test]), ("test", test)):
            (root / f"transforms_{name}.json").write_text(json.dumps({**db, "frames": part}))
    return codes, cams


def test_vhap_export_values_and_camera(tmp_path):
    codes, cams = write_vhap_export(tmp_path, timesteps=(0, 1, 2, 5))
    assert detect_format(tmp_path) == "vhap"
    seq = read_sequence(tmp_path, fps=30)
    assert (seq.format, len(seq), seq.fps, seq.image_size) == ("vhap", 4, 30.0, (520, 512))
    np.testing.assert_array_equal(seq.frame_ids, [0, 1, 2, 5])
    for ours, theirs in (
        ("expr", "expr"),
        ("jaw", "jaw_pose"),
        ("neck", "neck_pose"),
        ("eyes", "eyes_pose"),
        ("rotation", "rotation"),
        ("translation", "translation"),
    ):
        assert getattr(seq, ours).dtype == np.float64
        np.testing.assert_array_equal(getattr(seq, ours), codes[theirs])
    np.testing.assert_array_equal(seq.shape, np.repeat(codes["shape"][None], 4, axis=0))
    np.testing.assert_array_equal(seq.static_offset, codes["static_offset"][0])
    # Native convention: OpenGL camera-to-world; the camera looks down -z, image y down.
    cam = cams[0]
    pts = points(np.random.default_rng(1))
    gl = (np.linalg.inv(cam["c2w"]) @ np.c_[pts, np.ones(len(pts))].T)[:3]
    native = np.stack(
        [cam["cx"] + cam["fl_x"] * gl[0] / -gl[2], cam["cy"] - cam["fl_y"] * gl[1] / -gl[2]], axis=1
    )
    for t in range(len(seq)):
        np.testing.assert_allclose(project(seq, t, pts), native, atol=1e-9)


def test_vhap_multiview_picks_a_camera(tmp_path):
    _, cams = write_vhap_export(tmp_path, cameras=(3, 1, 8))
    with pytest.warns(InputWarning, match=r"3 cameras \[1, 3, 8\]; using camera 1"):
        seq = read_sequence(tmp_path, fps=25)
    np.testing.assert_allclose(seq.w2c[0], np.linalg.inv(cams[1]["c2w"] @ np.diag([1, -1, -1, 1])))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        seq = read_sequence(tmp_path, fps=25, camera=8)
    assert seq.K[2, 0, 0] == cams[8]["fl_x"]


def test_gaussian_avatars_split_transforms(tmp_path):
    codes, _ = write_vhap_export(tmp_path, timesteps=(0, 1, 2), split=True)
    seq = read_sequence(tmp_path, fps=25)
    np.testing.assert_array_equal(seq.frame_ids, [0, 1, 2])
    np.testing.assert_array_equal(seq.expr, codes["expr"])


def test_vhap_flame_param_folder_without_cameras(tmp_path):
    codes, _ = write_vhap_export(tmp_path, timesteps=(3, 4))
    seq = read_sequence(tmp_path / "flame_param", fps=25)
    assert seq.K is None and seq.w2c is None and seq.image_size is None
    np.testing.assert_array_equal(seq.frame_ids, [3, 4])
    np.testing.assert_array_equal(seq.eyes, codes["eyes_pose"])


def write_vhap_tracked(path, n=5, seed=2):
    """tracker.save_result's tracked_flame_params_<epoch>.npz (uncalibrated monocular)."""
    codes = vhap_codes(np.random.default_rng(seed), n)
    np.savez(
        path,
        **codes,
        timestep_id=np.array([f"{t:05d}" for t in range(n)]),
        n_processed_frames=n,
        focal_length=np.array([1.5], F32),
        tex=np.zeros(100, F32),
        lights=np.zeros((9, 3), F32),
        image_size=np.array([480, 640]),
    )
    return codes


def test_vhap_tracked_npz_and_its_camera(tmp_path):
    path = tmp_path / "tracked_flame_params_30.npz"
    codes = write_vhap_tracked(path)
    assert detect_format(path) == "vhap"
    seq = read_sequence(path, fps=25)
    np.testing.assert_array_equal(seq.rotation, codes["rotation"])
    np.testing.assert_array_equal(seq.shape, np.repeat(codes["shape"][None], 5, axis=0))
    np.testing.assert_array_equal(seq.frame_ids, np.arange(5))
    assert seq.image_size == (480, 640)
    # Camera at (0, 0, 1) looking at the origin, focal 1.5 * max(H, W), centred.
    f = 1.5 * 640
    np.testing.assert_allclose(
        project(seq, 0, np.array([[0.0, 0, 0], [0.1, 0.05, 0]])),
        [[320, 240], [320 + f * 0.1, 240 - f * 0.05]],
        atol=1e-9,
    )


# ---------------------------------------------------------------- metrical-tracker


def rot6d(aa):
    """PyTorch3D matrix_to_rotation_6d: the first two rows of the matrix."""
    return axis_angle_to_matrix(np.asarray(aa, dtype=np.float64))[..., :2, :].reshape(
        *np.shape(aa)[:-1], 6
    )


def write_metrical(folder, n=3, seed=3, tensors=False):
    """Tracker.save_checkpoint: checkpoint/<frame:05d>.frame, torch.save of numpy arrays."""
    rng = np.random.default_rng(seed)
    (folder / "checkpoint").mkdir(parents=True)
    truth = {"jaw": rng.normal(0, 0.2, (n, 3)), "eyes": rng.normal(0, 0.2, (n, 6)), "raw": []}
    for t in range(n):
        R = axis_angle_to_matrix(rng.normal(0, 0.3, 3))
        frame = {
            "flame": {
                "exp": rng.normal(0, 1, (1, 100)).astype(F32),
                "shape": rng.normal(0, 1, (1, 300)).astype(F32),
                "tex": np.zeros((1, 140), F32),
                "sh": np.zeros((1, 9, 3), F32),
                "eyes": rot6d(truth["eyes"][t].reshape(2, 3)).reshape(1, 12).astype(F32),
                "eyelids": rng.uniform(0, 1, (1, 2)).astype(F32),
                "jaw": rot6d(truth["jaw"][t])[None].astype(F32),
            },
            "camera": {
                "R": rot6d(np.zeros(3))[None].astype(F32),
                "t": np.array([[0, 0, 1]], F32),
                "fl": np.array([[9.7]], F32),
                "pp": np.zeros((1, 2), F32),
            },
            "opencv": {
                "R": R[None].astype(F32),
                "t": np.array([[0.01, -0.02, 1.1]], F32),
                "K": np.array([[[2500, 0, 256], [0, 2500, 256], [0, 0, 1]]], F32),
            },
            "img_size": np.array([512, 512]),
            "frame_id": f"{t:05d}",
            "global_step": 100 * t,
        }
        if tensors:
            frame["flame"] = {k: torch.from_numpy(v) for k, v in frame["flame"].items()}
            frame["opencv"] = {k: torch.from_numpy(v) for k, v in frame["opencv"].items()}
        torch.save(frame, folder / "checkpoint" / f"{t:05d}.frame")
        truth["raw"].append(frame)
    return truth


@pytest.mark.parametrize("tensors", [False, True])
def test_metrical_frames(tmp_path, tensors):
    truth = write_metrical(tmp_path, tensors=tensors)
    assert detect_format(tmp_path) == "metrical-tracker"
    seq = read_sequence(tmp_path, fps=25)
    raw = truth["raw"]
    as_np = [
        {s: {k: np.asarray(v) for k, v in f[s].items()} for s in ("flame", "opencv")} for f in raw
    ]
    np.testing.assert_array_equal(seq.expr, np.concatenate([f["flame"]["exp"] for f in as_np]))
    np.testing.assert_array_equal(seq.shape, np.concatenate([f["flame"]["shape"] for f in as_np]))
    np.testing.assert_array_equal(
        seq.eyelids, np.concatenate([f["flame"]["eyelids"] for f in as_np])
    )
    np.testing.assert_allclose(seq.jaw, truth["jaw"], atol=1e-6)  # float32 6D in the file
    np.testing.assert_allclose(seq.eyes, truth["eyes"], atol=1e-6)
    for name in ("rotation", "neck", "translation"):  # the camera carries the head pose
        np.testing.assert_array_equal(getattr(seq, name), 0.0)
    assert seq.image_size == (512, 512)
    np.testing.assert_array_equal(seq.frame_ids, [0, 1, 2])
    pts = points(np.random.default_rng(4))
    for t, f in enumerate(as_np):
        cv = f["opencv"]
        cam = cv["R"][0].astype(np.float64) @ pts.T + cv["t"][0, :, None]
        uvw = cv["K"][0].astype(np.float64) @ cam
        np.testing.assert_allclose(project(seq, t, pts), (uvw[:2] / uvw[2]).T, atol=1e-9)


def test_metrical_frames_read_without_torch(tmp_path):
    write_metrical(tmp_path)
    code = (
        "import sys; from archhead_addon.sequences import read_sequence; "
        f"assert len(read_sequence({str(tmp_path)!r}, fps=25)) == 3; "
        "assert 'torch' not in sys.modules, 'torch was imported'"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr


def test_metrical_single_frame_file(tmp_path):
    write_metrical(tmp_path, n=2)
    path = tmp_path / "checkpoint" / "00001.frame"
    assert detect_format(path) == "metrical-tracker"
    seq = read_sequence(path, fps=25)
    assert len(seq) == 1 and seq.frame_ids[0] == 1


# ---------------------------------------------------------------- flame-head-tracker


def their_euler(R):
    """tracker_base's rotation_matrix_to_euler_angles, as stored in `cam[:3]`."""
    pitch = np.arcsin(np.clip(-R[2, 0], -1, 1))
    yaw, roll = np.arctan2(R[1, 0], R[0, 0]), np.arctan2(R[2, 1], R[2, 2])
    return np.array([pitch, roll, yaw])


def their_projection(rotvec, position, K, pts, size=256, near=0.01, far=100.0):
    """tracker_base's batch_perspective_projection + clip->NDC->screen, in numpy."""
    Rt = np.eye(4)
    Rt[:3, :3], Rt[:3, 3] = axis_angle_to_matrix(rotvec), position
    Rt[:, [1, 2]] *= -1
    world2view = np.linalg.inv(Rt)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    proj = np.array(
        [
            [2 * fx / size, 0, (size - 2 * cx) / size, 0],
            [0, 2 * fy / size, (size - 2 * cy) / size, 0],
            [0, 0, (far + near) / (far - near), -2 * far * near / (far - near)],
            [0, 0, 1, 0],
        ]
    )
    full = proj @ world2view
    full[1] *= -1
    clip = np.c_[pts, np.ones(len(pts))] @ full.T
    ndc = clip[:, :3] / clip[:, 3:]
    ndc[:, 1] *= -1
    return ((ndc / 2 + 0.5) * size)[:, :2]


def write_fht(folder, n=3, seed=5, fov=20.0):
    """tracker_video: <frame>.npz (unpadded numbers) of run_fitting's ret_dict, leading dim 1."""
    rng = np.random.default_rng(seed)
    folder.mkdir(exist_ok=True)
    f = 0.5 * 256 / np.tan(np.radians(fov) / 2)
    K = np.array([[f, 0, 128], [0, f, 128], [0, 0, 1]], F32)
    cams = []
    for t in range(n):
        rotvec = rng.normal(0, 0.2, 3)
        position = np.r_[rng.normal(0, 0.02, 2), 1.0]
        cam = np.r_[their_euler(axis_angle_to_matrix(rotvec)), position].astype(F32)
        cams.append((rotvec, position))
        np.savez_compressed(
            folder / f"{t}.npz",
            shape=rng.normal(0, 1, (1, 300)).astype(F32),
            exp=rng.normal(0, 1, (1, 100)).astype(F32),
            head_pose=np.zeros((1, 3), F32),
            jaw_pose=rng.normal(0, 0.1, (1, 3)).astype(F32),
            neck_pose=rng.normal(0, 0.1, (1, 3)).astype(F32),
            eye_pose=rng.normal(0, 0.1, (1, 6)).astype(F32),
            tex=np.zeros((1, 50), F32),
            texture=np.zeros((1, 3, 4, 4), F32),
            light=np.zeros((1, 9, 3), F32),
            cam=cam[None],
            fov=np.array([fov], F32),
            K=K[None],
            img_rendered=np.zeros((1, 8, 8, 3), np.uint8),
            mesh_rendered=np.zeros((1, 8, 8, 3), np.uint8),
            img=np.zeros((1, 8, 8, 3), np.uint8),
            lmks_68=np.zeros((1, 68, 2), F32),
            blendshape_scores=np.zeros((1, 52), F32),
        )
    return cams


def test_flame_head_tracker_frames_and_camera(tmp_path):
    cams = write_fht(tmp_path, n=12)  # 0..11: numeric order, not name order
    assert detect_format(tmp_path) == "flame-head-tracker"
    seq = read_sequence(tmp_path, fps=25)
    np.testing.assert_array_equal(seq.frame_ids, np.arange(12))
    ten = np.load(tmp_path / "10.npz")
    for ours, theirs in (
        ("shape", "shape"),
        ("expr", "exp"),
        ("rotation", "head_pose"),
        ("jaw", "jaw_pose"),
        ("neck", "neck_pose"),
        ("eyes", "eye_pose"),
    ):
        np.testing.assert_array_equal(getattr(seq, ours)[10], ten[theirs][0])
    np.testing.assert_array_equal(seq.translation, 0.0)
    assert seq.image_size == (256, 256)
    pts = points(np.random.default_rng(6))
    for t, (rotvec, position) in enumerate(cams):
        native = their_projection(rotvec, position, seq.K[t], pts)
        np.testing.assert_allclose(project(seq, t, pts), native, atol=2e-3)  # float32 cam


def test_flame_head_tracker_without_K_uses_fov(tmp_path):
    write_fht(tmp_path, n=1, fov=25.0)
    arrays = dict(np.load(tmp_path / "0.npz"))
    K = arrays.pop("K")[0]
    np.savez(tmp_path / "0.npz", **arrays)
    seq = read_sequence(tmp_path / "0.npz", fps=25)
    np.testing.assert_allclose(seq.K[0], K, rtol=1e-6)
    assert seq.image_size == (256, 256)


# ---------------------------------------------------------------- driving clips


def clip_dict(n=6, seed=7):
    rng = np.random.default_rng(seed)
    return {
        "exp": rng.normal(0, 1, (n, 100)).astype(F32),
        "jaw": rng.normal(0, 0.1, (n, 3)).astype(F32),
        "fps": 30,
    }


def write_clip(path, kind, clip):
    if kind == "npz":
        np.savez(path, **clip)
    elif kind.startswith("pickle"):
        with open(path, "wb") as f:
            pickle.dump(clip, f, protocol=int(kind[-1]))
    else:
        torch.save(
            {k: torch.from_numpy(v) if isinstance(v, np.ndarray) else v for k, v in clip.items()},
            path,
        )


@pytest.mark.parametrize(
    "kind,suffix", [("npz", ".npz"), ("pickle2", ".pkl"), ("pickle5", ".pkl"), ("torch", ".pt")]
)
def test_driving_clip(tmp_path, kind, suffix):
    clip = clip_dict()
    path = tmp_path / f"clip{suffix}"
    write_clip(path, kind, clip)
    assert detect_format(path) == "driving-clip"
    seq = read_sequence(path)
    assert (seq.fps, len(seq), seq.shape.shape, seq.K) == (30.0, 6, (6, 0), None)
    np.testing.assert_array_equal(seq.expr, clip["exp"])
    np.testing.assert_array_equal(seq.jaw, clip["jaw"])
    np.testing.assert_array_equal(seq.eyes, 0.0)
    assert read_sequence(path, fps=60).fps == 60.0


# ---------------------------------------------------------------- round trips


def _write_any(kind, root):
    root.mkdir()
    if kind == "vhap-export":
        write_vhap_export(root)
        return root
    if kind == "vhap-tracked":
        write_vhap_tracked(root / "tracked_flame_params.npz")
        return root / "tracked_flame_params.npz"
    if kind == "metrical":
        write_metrical(root)
        return root
    if kind == "flame-head-tracker":
        write_fht(root)
        return root
    write_clip(root / "clip.pt", "torch", clip_dict())
    return root / "clip.pt"


@pytest.mark.parametrize(
    "kind", ["vhap-export", "vhap-tracked", "metrical", "flame-head-tracker", "driving"]
)
def test_round_trip_through_canonical(tmp_path, kind):
    seq = read_sequence(_write_any(kind, tmp_path / "in"), fps=24)
    write_canonical(seq, tmp_path / "out.npz")
    back = read_canonical(tmp_path / "out.npz")
    assert back.format == "canonical" and back.data_equal(seq)
    with np.load(tmp_path / "out.npz") as z:
        assert str(z["source_format"]) == seq.format and int(z["format_version"]) == 1
