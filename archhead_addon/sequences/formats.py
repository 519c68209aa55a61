"""Which reader a path needs, and `read_sequence`, the one entry point for all of them."""

from __future__ import annotations

from pathlib import Path

from ..io.errors import InputError
from . import canonical, driving, flame_head_tracker, metrical, vhap
from .common import load_npz
from .sequence import Sequence

READERS = {
    canonical.NAME: canonical.read_canonical,
    vhap.NAME: vhap.read_vhap,
    metrical.NAME: metrical.read_metrical,
    flame_head_tracker.NAME: flame_head_tracker.read_flame_head_tracker,
    driving.NAME: driving.read_driving_clip,
}
FORMAT_NAMES = tuple(READERS)

SUPPORTED = (
    "supported formats: canonical (ArchHead .npz with 'format_version'); vhap (VHAP / "
    "GaussianAvatars folder with flame_param/ and transforms.json, or tracked_flame_params.npz); "
    "metrical-tracker (.frame file, or a folder of them or its checkpoint/); flame-head-tracker "
    "(per-frame .npz with head_pose, eye_pose, cam, or a folder of them); driving-clip (.npz, "
    ".pkl or .pt dict with exp, jaw, fps)"
)


def _npz_format(arrays: dict) -> str | None:
    if canonical.is_canonical(arrays):
        return canonical.NAME
    if flame_head_tracker.is_fht_frame(arrays):
        return flame_head_tracker.NAME
    if vhap.is_vhap_params(arrays):
        return vhap.NAME
    if driving.is_driving_clip(arrays):
        return driving.NAME
    return None


def detect_format(path) -> str:
    """The format name for `path`, from its suffix, the folder's contents or the npz keys."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, None, "not found")
    if path.is_dir():
        found = _folder_format(path)
    elif path.suffix.lower() == ".frame":
        found = metrical.NAME
    elif path.suffix.lower() == ".npz":
        arrays = load_npz(path)
        found = _npz_format(arrays)
        if found is None:
            raise InputError(
                path, None, f"an npz with keys {sorted(arrays)[:12]} matches no format; {SUPPORTED}"
            )
    elif path.suffix.lower() in (".pkl", ".pickle", ".pt", ".pth"):
        found = driving.NAME
    else:
        found = None
    if found is None:
        raise InputError(path, None, f"unrecognised input; {SUPPORTED}")
    return found


def _folder_format(folder: Path) -> str | None:
    if (folder / "flame_param").is_dir() or vhap.transforms_files(folder):
        return vhap.NAME
    if any(metrical.frame_folder(folder).glob("*.frame")):
        return metrical.NAME
    npz = sorted(folder.glob("*.npz"))
    if npz:
        found = _npz_format(load_npz(npz[0]))
        if found in (vhap.NAME, flame_head_tracker.NAME):
            return found
    return None


def read_sequence(
    path, format: str | None = None, *, fps: float | None = None, camera: int | None = None
) -> Sequence:
    """Read any supported sequence; `format` overrides detection.

    `fps` sets the frame rate (for formats that store one, it overrides the stored value);
    `camera` picks the camera_index of a multi-view VHAP / GaussianAvatars folder.
    """
    if not Path(path).exists():
        raise InputError(path, None, "not found")
    name = format or detect_format(path)
    if name not in READERS:
        raise InputError(path, None, f"unknown format '{name}'; {SUPPORTED}")
    if camera is not None and name != vhap.NAME:
        raise InputError(path, None, f"a camera choice applies to {vhap.NAME} input, not {name}")
    options = {} if camera is None else {"camera": camera}
    return READERS[name](path, fps=fps, **options)
