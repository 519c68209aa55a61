"""VHAP / GaussianAvatars tracked sequences.

Layouts (as VHAP's `export_as_nerf_dataset` writes them and GaussianAvatars reads them):

- an exported folder: `flame_param/<timestep:05d>.npz`, one per timestep, with `shape` (S,)
  (or (1,S)), `expr` (1,E), `rotation`, `neck_pose`, `jaw_pose`, `translation` (1,3),
  `eyes_pose` (1,6), optional `static_offset` (1,V,3) (same in every file; the first is used;
  `dynamic_offset` is ignored); cameras in `transforms.json` (or `transforms_{train,val,test}
  .json`): `frames` with `timestep_index`, `camera_index`, `flame_param_path`,
  `transform_matrix` (camera-to-world, OpenGL camera axes), `fl_x`, `fl_y`, `cx`, `cy` in
  pixels and `w`, `h` (per frame, or at the top level). Several cameras per timestep
  (multi-view): one is used, by default the lowest `camera_index`. Frame ids are timestep
  indices. Without a transforms file the folder (or `flame_param/` itself) is read without
  cameras, frame ids from the file names.
- the tracker's own `tracked_flame_params[_<epoch>].npz`: the same keys with T rows (`shape`
  once), frame ids 0..T-1. When it was tracked without calibration it holds `focal_length`
  (normalised by max(H, W)) and `image_size` (H, W): VHAP's camera sits at (0, 0, 1) with the
  identity rotation, looking down -z (OpenGL), principal point at the image centre.

Pose keys map to ours as rotation -> rotation, neck_pose -> neck, jaw_pose -> jaw,
eyes_pose -> eyes. No frame rate is stored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.errors import InputError, warn_input
from ..io.json_input import json_number, load_json
from .cameras import intrinsics, w2c_from_opengl_c2w
from .common import get, load_npz, numbered_files, resolve_fps
from .sequence import Sequence
from .validation import check_frame_count

NAME = "vhap"
_POSES = (
    ("rotation", "rotation", 3),
    ("neck_pose", "neck", 3),
    ("jaw_pose", "jaw", 3),
    ("eyes_pose", "eyes", 6),
    ("translation", "translation", 3),
)
_INTRINSICS = ("fl_x", "fl_y", "cx", "cy", "w", "h")


def is_vhap_params(arrays: dict) -> bool:
    return {"expr", "eyes_pose", "jaw_pose"} <= set(arrays)


def transforms_files(folder: Path) -> list[Path]:
    """`transforms.json`, else the split files GaussianAvatars reads, that exist."""
    whole = folder / "transforms.json"
    if whole.is_file():
        return [whole]
    return [
        p
        for split in ("train", "val", "test")
        if (p := folder / f"transforms_{split}.json").is_file()
    ]


def read_vhap(path, *, fps=None, camera: int | None = None) -> Sequence:
    path = Path(path)
    if path.is_file():
        return _read_tracked_npz(path, fps)
    if transforms_files(path):
        return _read_exported(path, fps, camera)
    folder = path / "flame_param" if (path / "flame_param").is_dir() else path
    numbered = numbered_files(folder, ".npz")
    rows = [_rows(load_npz(p), p, frame=n, single=True) for n, p in numbered]
    return _sequence(rows, [n for n, _ in numbered], path, resolve_fps(fps, path))


def _rows(arrays: dict, path: Path, frame=None, single=False) -> dict:
    """The codes of one npz as arrays with one row per timestep."""
    expr = get(arrays, "expr", path, ("T", "E"), frame=frame, along="frame")
    n = len(expr)
    if single and n != 1:
        raise InputError(path, "expr", f"expected one timestep per file, found {n}")
    check_frame_count(n, path)  # before the identity and the cameras are repeated n times
    rows = {"expr": expr, "path": path}
    for key, name, width in _POSES:
        rows[name] = get(arrays, key, path, (n, width), frame=frame, along="frame")
    shape = get(arrays, "shape", path, ("S",), (1, "S"), frame=frame)
    if not shape.size:  # VHAP always fits FLAME's identity (300 coefficients)
        raise InputError(path, "shape", "no identity coefficients (VHAP writes FLAME's 300)")
    rows["shape"] = np.repeat(shape.reshape(1, -1), n, axis=0)
    offset = get(arrays, "static_offset", path, (1, "V", 3), ("V", 3), frame=frame, default=None)
    rows["static_offset"] = None if offset is None else offset.reshape(-1, 3)
    return rows


def _sequence(rows: list[dict], frame_ids, source, fps, **camera) -> Sequence:
    for key in ("shape", "expr"):  # the poses' widths are fixed by `_rows`
        width = rows[0][key].shape[1]
        for r in rows[1:]:
            if r[key].shape[1] != width:
                raise InputError(
                    r["path"],
                    key,
                    f"{r[key].shape[1]} coefficients, {rows[0]['path']} has {width}: "
                    "every frame file must have the same widths",
                )
    stacked = {
        name: np.concatenate([r[name] for r in rows])
        for name in ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")
    }
    return Sequence(
        **stacked,
        static_offset=rows[0]["static_offset"],
        fps=fps,
        frame_ids=frame_ids,
        source=str(source),
        format=NAME,
        **camera,
    ).validate()


def _read_tracked_npz(path: Path, fps) -> Sequence:
    arrays = load_npz(path)
    rows = _rows(arrays, path)
    n = len(rows["expr"])
    camera = {}
    if ("focal_length" in arrays) != ("image_size" in arrays):
        key = "image_size" if "focal_length" in arrays else "focal_length"
        raise InputError(path, key, "missing: VHAP writes focal_length and image_size together")
    if "focal_length" in arrays:
        focal = float(get(arrays, "focal_length", path, (), (1,)).reshape(()))
        h, w = (int(v) for v in get(arrays, "image_size", path, (2,)))
        f = focal * max(h, w)
        c2w = np.eye(4)
        c2w[2, 3] = 1.0
        camera = {
            "K": np.repeat(intrinsics(f, f, w / 2, h / 2)[None], n, axis=0),
            "w2c": np.repeat(w2c_from_opengl_c2w(c2w, path, "focal_length")[None], n, axis=0),
            "image_size": (h, w),
        }
    return _sequence([rows], np.arange(n), path, resolve_fps(fps, path), **camera)


def _load_frames(files: list[Path]) -> list[tuple[Path, int, dict, dict]]:
    """(json file, index, frame, top level) for every frame of the transforms files."""
    out = []
    for file in files:
        top = load_json(file)
        frames = top.get("frames") if isinstance(top, dict) else None
        if not isinstance(frames, list) or not all(isinstance(f, dict) for f in frames):
            raise InputError(file, "frames", "missing or not a list of objects")
        out += [(file, i, frame, top) for i, frame in enumerate(frames)]
    if not out:
        raise InputError(files[0], "frames", "the sequence has no frames")
    return out


def _read_exported(folder: Path, fps, camera: int | None) -> Sequence:
    frames = _load_frames(transforms_files(folder))
    for file, i, frame, _ in frames:
        for key, default in (("timestep_index", None), ("camera_index", 0)):
            value = frame.get(key, default)
            # a JSON true or false is an int to Python: true would stand for timestep 1; past
            # int64 numpy cannot hold it (frame ids past 2^31 - 1 are refused by validation)
            if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 1 << 63:
                raise InputError(
                    file,
                    f"frames[{i}].{key}",
                    f"expected a whole number in 0..2^63-1, found {value!r:.40}",
                )
    cameras = sorted({frame.get("camera_index", 0) for _, _, frame, _ in frames})
    chosen = cameras[0] if camera is None else camera
    if chosen not in cameras:
        raise InputError(frames[0][0], "camera_index", f"camera {chosen} not among {cameras}")
    if camera is None and len(cameras) > 1:
        warn_input(
            frames[0][0],
            "camera_index",
            f"{len(cameras)} cameras {cameras}; using "
            f"camera {chosen} (pass camera= or --camera to choose)",
        )
    seen: dict[tuple, tuple] = {}
    paths: dict[object, int] = {}
    for file, i, frame, _ in frames:
        pair = (frame["timestep_index"], frame.get("camera_index", 0))
        if pair in seen:  # two images of one camera at one instant: a frame listed twice
            first = seen[pair]
            raise InputError(
                file,
                f"frames[{i}]",
                f"timestep {pair[0]} of camera {pair[1]} again (first at "
                f"{first[0].name} frames[{first[1]}]): each timestep has one frame per camera",
            )
        seen[pair] = (file, i)
        rel = frame.get("flame_param_path")
        other = paths.setdefault(rel, pair[0]) if isinstance(rel, str) else pair[0]
        if other != pair[0]:  # a timestep's codes are its own (its cameras share them)
            raise InputError(
                file,
                f"frames[{i}].flame_param_path",
                f"{rel!r:.60} is also timestep {other}'s: timestep {pair[0]} needs its own",
            )
    selected: dict[int, tuple] = {}
    for entry in frames:
        if entry[2].get("camera_index", 0) == chosen:
            selected.setdefault(entry[2]["timestep_index"], entry)
    missing = sorted({f["timestep_index"] for _, _, f, _ in frames} - set(selected))
    if missing:
        raise InputError(
            frames[0][0], "frames", f"timesteps {missing[:8]} have no frame from camera {chosen}"
        )
    timesteps = sorted(selected)
    rows, Ks, w2cs, sizes = [], [], [], set()
    for t in timesteps:
        file, i, frame, top = selected[t]
        rel = frame.get("flame_param_path")
        if not isinstance(rel, str):
            raise InputError(file, f"frames[{i}].flame_param_path", "missing")
        try:
            inside = (folder / rel).resolve().is_relative_to(folder.resolve())
        except (OSError, ValueError) as exc:  # a NUL byte, a name too long for the system
            raise InputError(
                file, f"frames[{i}].flame_param_path", f"not a usable path ({exc!s:.80})"
            ) from exc
        if not inside:
            raise InputError(file, f"frames[{i}].flame_param_path", "outside the sequence folder")
        rows.append(_rows(load_npz(folder / rel), folder / rel, frame=t, single=True))
        values = {}
        for key in _INTRINSICS:
            values[key] = json_number(
                frame.get(key, top.get(key)), file, f"frames[{i}].{key}", minimum=-1e9
            )
        for key in ("fl_x", "fl_y"):
            if values[key] <= 0:
                raise InputError(
                    file,
                    f"frames[{i}].{key}",
                    f"focal length {values[key]:g} pixels: expected > 0 (a negative one mirrors)",
                )
        sizes.add((int(values["h"]), int(values["w"])))
        Ks.append(intrinsics(values["fl_x"], values["fl_y"], values["cx"], values["cy"]))
        c2w = get(
            frame, "transform_matrix", file, (4, 4), frame=t, name=f"frames[{i}].transform_matrix"
        )
        w2cs.append(w2c_from_opengl_c2w(c2w, file, f"frames[{i}].transform_matrix"))
    if len(sizes) > 1:
        raise InputError(frames[0][0], "w/h", f"frames differ in image size: {sorted(sizes)}")
    return _sequence(
        rows,
        timesteps,
        folder,
        resolve_fps(fps, folder),
        K=np.stack(Ks),
        w2c=np.stack(w2cs),
        image_size=sizes.pop(),
    )
