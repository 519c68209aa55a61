"""Bad input to the sequence readers: one clear error naming the file, the key and the problem."""

import json
import pickle
import re

import numpy as np
import pytest
import torch
from test_sequences import make_sequence
from test_sequences_formats import (
    clip_dict,
    write_clip,
    write_fht,
    write_metrical,
    write_vhap_export,
    write_vhap_tracked,
)

from archhead_addon.io.errors import InputError
from archhead_addon.sequences import read_sequence, write_canonical


def _edit_npz(path, **changes):
    arrays = dict(np.load(path))
    arrays.update(changes)
    for key in [k for k, v in changes.items() if v is None]:
        del arrays[key]
    np.savez(path, **arrays)


def _edit_frame(path, edit):
    frame = torch.load(path, weights_only=False)
    edit(frame)
    torch.save(frame, path)


def _raises(path, key, problem, *args, **kwargs):
    """read_sequence fails with `<file>: key '<key>': <problem>` (regex for the problem)."""
    where = f"{path}: key '{key}': " if key else f"{path}: "
    with pytest.raises(InputError, match="^" + _escape(where) + problem):
        read_sequence(*args, **{"fps": 25, **kwargs})


def _escape(text):
    return re.escape(str(text))


# ---------------------------------------------------------------- missing keys


def test_missing_keys(tmp_path):
    write_vhap_export(tmp_path / "v")
    param = tmp_path / "v" / "flame_param" / "00002.npz"
    _edit_npz(param, jaw_pose=None)
    _raises(param, "jaw_pose", "missing", tmp_path / "v")

    write_metrical(tmp_path / "m")
    frame = tmp_path / "m" / "checkpoint" / "00001.frame"
    _edit_frame(frame, lambda f: f["flame"].pop("exp"))
    _raises(frame, "flame.exp", "missing", tmp_path / "m")
    _edit_frame(frame, lambda f: f.pop("opencv"))
    _raises(frame, "opencv", "missing or not a dict", tmp_path / "m")

    write_fht(tmp_path / "f")
    _edit_npz(tmp_path / "f" / "1.npz", cam=None)
    _raises(tmp_path / "f" / "1.npz", "cam", "missing", tmp_path / "f")

    clip = clip_dict()
    del clip["fps"]
    write_clip(tmp_path / "clip.pt", "torch", clip)
    _raises(tmp_path / "clip.pt", "fps", "missing", tmp_path / "clip.pt", fps=None)


def test_missing_transforms_entries(tmp_path):
    write_vhap_export(tmp_path)
    db = json.loads((tmp_path / "transforms.json").read_text())
    del db["frames"][1]["flame_param_path"]
    (tmp_path / "transforms.json").write_text(json.dumps(db))
    _raises(tmp_path / "transforms.json", "frames[1].flame_param_path", "missing", tmp_path)
    del db["frames"][0]["fl_x"], db["fl_x"]
    (tmp_path / "transforms.json").write_text(json.dumps(db))
    _raises(
        tmp_path / "transforms.json", "frames[0].fl_x", "missing or not a finite number", tmp_path
    )


# ---------------------------------------------------------------- wrong shapes


def test_wrong_shapes(tmp_path):
    write_vhap_export(tmp_path / "v")
    param = tmp_path / "v" / "flame_param" / "00000.npz"
    _edit_npz(param, eyes_pose=np.zeros((1, 3), np.float32))
    _raises(param, "eyes_pose", r"expected shape \(1, 6\), found \(1, 3\)", tmp_path / "v")

    write_fht(tmp_path / "f")
    _edit_npz(tmp_path / "f" / "0.npz", exp=np.zeros((2, 100), np.float32))
    _raises(
        tmp_path / "f" / "0.npz",
        "exp",
        r"expected shape \(1, E\), found \(2, 100\)",
        tmp_path / "f",
    )

    write_metrical(tmp_path / "m", n=1)
    frame = tmp_path / "m" / "checkpoint" / "00000.frame"
    _edit_frame(frame, lambda f: f["flame"].update(jaw=np.zeros((1, 3), np.float32)))
    _raises(frame, "flame.jaw", r"expected shape \(1, 6\)", tmp_path / "m")

    clip = clip_dict()
    clip["jaw"] = np.zeros((6, 6), np.float32)
    write_clip(tmp_path / "c.npz", "npz", clip)
    _raises(
        tmp_path / "c.npz", "jaw", r"expected shape \(6, 3\), found \(6, 6\)", tmp_path / "c.npz"
    )


@pytest.mark.parametrize(
    "key, value, problem",
    [
        ("jaw", np.zeros((1, 6)), r"degenerate 6D rotation in frame 1: \[0\.0, 0\.0, 0\.0, 0"),
        ("jaw", [[0, 2, 0, 0, -1, 0]], "degenerate 6D rotation in frame 1"),  # parallel
        ("eyes", [[1, 0, 0, 0, 1, 0] + [0] * 6], r"degenerate 6D rotation \(rotation 1\)"),
    ],
)
def test_degenerate_6d_rotations(tmp_path, key, value, problem):
    write_metrical(tmp_path, n=2)
    frame = tmp_path / "checkpoint" / "00001.frame"
    _edit_frame(frame, lambda f: f["flame"].update({key: np.array(value, np.float32)}))
    _raises(frame, f"flame.{key}", problem, tmp_path)


def test_images_of_different_sizes(tmp_path):
    write_metrical(tmp_path, n=2)
    _edit_frame(
        tmp_path / "checkpoint" / "00001.frame", lambda f: f.update(img_size=np.array([256, 256]))
    )
    _raises(
        tmp_path,
        "img_size",
        r"frames differ in image size: \[\(256, 256\), \(512, 512\)\]",
        tmp_path,
    )


# ---------------------------------------------------------------- NaN / Inf


def test_nan_and_inf(tmp_path):
    write_vhap_export(tmp_path / "v")
    param = tmp_path / "v" / "flame_param" / "00003.npz"
    _edit_npz(param, expr=np.full((1, 100), np.nan, np.float32))
    _raises(param, "expr", r"NaN or Inf \(frame 3\)", tmp_path / "v")

    path = tmp_path / "tracked.npz"
    codes = write_vhap_tracked(path)
    rotation = codes["rotation"].copy()
    rotation[2, 1] = np.inf
    _edit_npz(path, rotation=rotation)
    _raises(path, "rotation", "NaN or Inf at frame index 2", path)

    write_vhap_tracked(tmp_path / "clean.npz")
    write_canonical(read_sequence(tmp_path / "clean.npz", fps=25), tmp_path / "canonical.npz")
    expr = np.load(tmp_path / "canonical.npz")["expr"]
    expr[1, 5] = np.nan
    _edit_npz(tmp_path / "canonical.npz", expr=expr)
    _raises(
        tmp_path / "canonical.npz",
        "expr",
        "NaN or Inf at frame index 1",
        tmp_path / "canonical.npz",
    )

    clip = clip_dict()
    clip["exp"][4, 0] = -np.inf
    write_clip(tmp_path / "c.pkl", "pickle5", clip)
    _raises(tmp_path / "c.pkl", "exp", "NaN or Inf at frame index 4", tmp_path / "c.pkl")


# ---------------------------------------------------------------- empty sequences


def test_empty_sequences(tmp_path):
    clip = {"exp": np.zeros((0, 100), np.float32), "jaw": np.zeros((0, 3), np.float32), "fps": 30}
    write_clip(tmp_path / "c.npz", "npz", clip)
    _raises(tmp_path / "c.npz", "expr", "the sequence has no frames", tmp_path / "c.npz")

    (tmp_path / "f").mkdir()
    _raises(
        tmp_path / "f",
        None,
        r"no '\*.npz' files in this folder",
        tmp_path / "f",
        "flame-head-tracker",
    )

    write_vhap_export(tmp_path / "v")
    (tmp_path / "v" / "transforms.json").write_text(json.dumps({"frames": []}))
    _raises(
        tmp_path / "v" / "transforms.json", "frames", "the sequence has no frames", tmp_path / "v"
    )


# ---------------------------------------------------------------- truncated / corrupt files


def test_truncated_and_corrupt_files(tmp_path):
    write_vhap_export(tmp_path / "v")
    param = tmp_path / "v" / "flame_param" / "00001.npz"
    param.write_bytes(param.read_bytes()[:300])
    _raises(param, None, "not a readable npz archive", tmp_path / "v")

    write_fht(tmp_path / "f")
    (tmp_path / "f" / "2.npz").write_bytes(b"\x00garbage" * 50)
    _raises(tmp_path / "f" / "2.npz", None, "not a readable npz archive", tmp_path / "f")

    write_metrical(tmp_path / "m")
    frame = tmp_path / "m" / "checkpoint" / "00002.frame"
    frame.write_bytes(frame.read_bytes()[:-200])
    _raises(frame, None, "not a torch.save zip archive", tmp_path / "m")
    torch.save({"flame": {}}, frame, _use_new_zipfile_serialization=False)
    _raises(frame, None, "legacy torch.save format", tmp_path / "m")

    (tmp_path / "c.pkl").write_bytes(pickle.dumps(clip_dict())[:-40])
    _raises(tmp_path / "c.pkl", None, "not a readable pickle", tmp_path / "c.pkl")


def test_pickled_clip_with_foreign_class_is_refused(tmp_path):
    clip = clip_dict()
    clip["extra"] = torch.nn.Identity()  # any class outside the allow-list
    with open(tmp_path / "c.pkl", "wb") as f:
        pickle.dump(clip, f)
    _raises(
        tmp_path / "c.pkl",
        None,
        "pickle refers to 'torch.nn.modules.linear.Identity'",
        tmp_path / "c.pkl",
    )


# ---------------------------------------------------------------- mixed frame numbering


@pytest.mark.parametrize(
    "names,problem",
    [
        (
            ["00000.npz", "00001.npz", "7.npz"],
            r"mixed frame numbering \(most are zero-padded to 5 "
            r"digits\): 7.npz$",
        ),
        (["0.npz", "1.npz", "01.npz"], r"duplicate frame numbers: 01.npz, 1.npz$"),
        (
            ["0.npz", "1.npz", "frame_2.npz"],
            r"mixed frame file names \(most start with ''\): "
            r"frame_2.npz$",
        ),
        (
            ["0.npz", "1.npz", "final.npz"],
            r"files without a frame number in their name: final.npz$",
        ),
    ],
)
def test_mixed_frame_numbering(tmp_path, names, problem):
    write_fht(tmp_path / "one", n=1)
    (tmp_path / "mixed").mkdir()
    for name in names:
        (tmp_path / "mixed" / name).write_bytes((tmp_path / "one" / "0.npz").read_bytes())
    _raises(tmp_path / "mixed", None, problem, tmp_path / "mixed", "flame-head-tracker")


# ---------------------------------------------------------------- values no tracker writes


def test_booleans_where_numbers_belong(tmp_path):
    """A bool array reads as 0/1 after a cast: refused in every container, naming the key."""
    for kind, suffix in (("npz", ".npz"), ("pickle2", ".pkl"), ("torch", ".pt")):
        clip = clip_dict()
        clip["exp"] = clip["exp"] > 0
        path = tmp_path / f"clip{suffix}"
        write_clip(path, kind, clip)
        _raises(path, "exp", "booleans where numbers are expected", path)
    write_metrical(tmp_path / "m")
    frame = tmp_path / "m" / "checkpoint" / "00001.frame"
    _edit_frame(frame, lambda f: f.update(img_size=np.array([True, True])))
    _raises(frame, "img_size", "booleans", tmp_path / "m")


def test_subnormal_float32_values_are_flushed_with_a_warning(tmp_path):
    from archhead_addon.io.errors import InputWarning

    clip = clip_dict()
    clip["jaw"][2, 1] = np.float32(7e-43)  # a zero with damaged exponent bits
    write_clip(tmp_path / "c.npz", "npz", clip)
    with pytest.warns(InputWarning, match="key 'jaw': 1 subnormal float32 value"):
        seq = read_sequence(tmp_path / "c.npz")
    assert seq.jaw[2, 1] == 0


@pytest.mark.parametrize(
    "row, value",
    [((2, 0), 0.5), ((2, 2), 1e6), ((1, 0), 3.0)],
    ids=["last row 0.5 0 1", "last row 0 0 1e6", "lower triangle"],
)
def test_intrinsics_that_are_no_pinhole_camera(tmp_path, row, value):
    write_metrical(tmp_path / "m")
    frame = tmp_path / "m" / "checkpoint" / "00002.frame"

    def edit(f):
        f["opencv"]["K"][(0, *row)] = value

    _edit_frame(frame, edit)
    _raises(tmp_path / "m", "K", "not pinhole intrinsics at frame index 2", tmp_path / "m")


def test_frame_ids_beyond_32_bits(tmp_path):
    write_vhap_export(tmp_path / "v")
    path = tmp_path / "v" / "transforms.json"
    top = json.loads(path.read_text())
    top["frames"][-1]["timestep_index"] = 1 << 62
    path.write_text(json.dumps(top))
    _raises(tmp_path / "v", "frame_ids", f"frame id {1 << 62} outside 0..2147483647", path.parent)


def test_vhap_frames_listed_twice_or_sharing_codes(tmp_path):
    write_vhap_export(tmp_path / "v")
    path = tmp_path / "v" / "transforms.json"
    good = json.loads(path.read_text())
    top = json.loads(json.dumps(good))
    top["frames"][1]["timestep_index"] = 0
    path.write_text(json.dumps(top))
    _raises(path, "frames[1]", "timestep 0 of camera 0 again", tmp_path / "v")
    top = json.loads(json.dumps(good))
    top["frames"][1]["flame_param_path"] = top["frames"][0]["flame_param_path"]
    path.write_text(json.dumps(top))
    _raises(path, "frames[1].flame_param_path", ".* is also timestep 0's", tmp_path / "v")


def test_vhap_tracked_half_a_camera_or_no_identity(tmp_path):
    path = tmp_path / "tracked_flame_params.npz"
    for missing in ("image_size", "focal_length"):
        write_vhap_tracked(path)
        _edit_npz(path, **{missing: None})
        _raises(path, missing, "missing: VHAP writes focal_length and image_size", path)
    write_vhap_tracked(path)
    _edit_npz(path, shape=np.zeros(0, np.float32))
    _raises(path, "shape", "no identity coefficients", path)


def test_metrical_6d_of_huge_parallel_vectors(tmp_path):
    write_metrical(tmp_path / "m")
    frame = tmp_path / "m" / "checkpoint" / "00000.frame"
    _edit_frame(frame, lambda f: f["flame"].update(jaw=np.full((1, 6), 1e30, np.float32)))
    _raises(frame, "flame.jaw", "degenerate 6D rotation", tmp_path / "m")


def test_head_behind_the_camera(tmp_path):
    """A tracked head is in front of its camera: a translation that puts it behind (a
    canonical npz's, 0.4 m behind its identity camera on one frame) or a camera turned away
    from it (metrical-tracker's `opencv.t`, the head pose, negated) is refused, naming the key,
    the frame index and the depth."""
    path = tmp_path / "behind.npz"
    write_canonical(make_sequence(), path)
    translation = np.load(path)["translation"]
    translation[3] = [0.0, 0.1, -0.4]
    _edit_npz(path, translation=translation)
    _raises(
        path,
        "translation",
        r"the head is behind the camera at frame index 3 \(frame id 13, "
        r"depth -0\.4 m\)",
        path,
    )

    write_metrical(tmp_path / "m")
    frame = tmp_path / "m" / "checkpoint" / "00002.frame"

    def edit(f):
        f["opencv"]["t"] *= -1

    _edit_frame(frame, edit)
    _raises(
        tmp_path / "m",
        "w2c",
        r"the head is behind the camera at frame index 2 .*depth -1\.1 m",
        tmp_path / "m",
    )
