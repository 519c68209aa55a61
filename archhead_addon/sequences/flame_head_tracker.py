"""flame-head-tracker per-frame `.npz` files (PeizhiYan/flame-head-tracker, v4.x `ret_dict`).

Video tracking saves `<frame>.npz` (unpadded numbers: 0.npz, 1.npz, ... 10.npz), leading dim 1:

    shape (1,S)  exp (1,E)  head_pose (1,3)  jaw_pose (1,3)  eye_pose (1,6)
    neck_pose (1,3) (photometric fitting only; zero when absent)
    cam (1,6)    camera pose: three angles (radians), then the camera position (x, y, z)
    fov (1,)     degrees;  K (1,3,3) pixels for the 256x256 render the fit used
    tex, light, img, img_rendered, ... (not used)

The camera: `cam[:3]` are Euler angles as the tracker writes them (its
`rotation_vector_to_euler_angles`): the camera-to-world rotation is
Rz(cam[2]) @ Ry(cam[0]) @ Rx(cam[1]); `cam[3:]` is the camera centre; the camera axes are
OpenGL's (the tracker negates y and z before inverting, to project the OpenCV way). K has the
principal point at the image centre, so the image is (2 cy, 2 cx); without K, K follows from
`fov` for the 256-pixel render. `head_pose` is the global rotation (the tracker zeroes it and
moves the camera instead); there is no translation. No frame rate is stored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.errors import InputError
from ..rotations import axis_angle_to_matrix
from .cameras import intrinsics, w2c_from_opengl_c2w
from .common import frame_number, get, load_npz, numbered_files, resolve_fps
from .sequence import Sequence

NAME = "flame-head-tracker"
RENDER_SIZE = 256  # the tracker's fixed render size, which K and fov refer to


def is_fht_frame(arrays: dict) -> bool:
    return {"head_pose", "eye_pose", "cam"} <= set(arrays)


def camera_to_world(cam: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world (OpenGL camera axes) from the tracker's 6-value `cam`."""
    a0, a1, a2 = cam[:3]
    c2w = np.eye(4)
    c2w[:3, :3] = (
        axis_angle_to_matrix(np.array([0.0, 0.0, a2]))
        @ axis_angle_to_matrix(np.array([0.0, a0, 0.0]))
        @ axis_angle_to_matrix(np.array([a1, 0.0, 0.0]))
    )
    c2w[:3, 3] = cam[3:6]
    return c2w


def read_flame_head_tracker(path, *, fps=None) -> Sequence:
    path = Path(path)
    files = [(frame_number(path), path)] if path.is_file() else numbered_files(path, ".npz")
    frames = [_read_frame(load_npz(file), file, number) for number, file in files]
    stacked = {key: np.stack([f[key] for f in frames]) for key in frames[0]}
    sizes = {(round(2 * k[1, 2]), round(2 * k[0, 2])) for k in stacked["K"]}
    if len(sizes) > 1:
        raise InputError(path, "K", f"frames differ in image size (2 cy, 2 cx): {sorted(sizes)}")
    return Sequence(
        **stacked,
        translation=np.zeros((len(frames), 3)),
        image_size=sizes.pop(),
        frame_ids=[n for n, _ in files],
        fps=resolve_fps(fps, path),
        source=str(path),
        format=NAME,
    ).validate()


def _read_frame(arrays: dict, path: Path, number: int) -> dict:
    def value(key, width, **kw):
        return get(arrays, key, path, (1, width), frame=number, **kw).reshape(-1)

    cam = value("cam", 6)
    K = get(arrays, "K", path, (1, 3, 3), frame=number, default=None)
    if K is None:
        fov = get(arrays, "fov", path, (1,), (), frame=number).reshape(())
        f = 0.5 * RENDER_SIZE / np.tan(np.radians(fov) / 2)
        K = intrinsics(f, f, RENDER_SIZE / 2, RENDER_SIZE / 2)
    return {
        "shape": value("shape", "S"),
        "expr": value("exp", "E"),
        "rotation": value("head_pose", 3),
        "jaw": value("jaw_pose", 3),
        "neck": value("neck_pose", 3, default=np.zeros((1, 3))),
        "eyes": value("eye_pose", 6),
        "K": K.reshape(3, 3),
        "w2c": w2c_from_opengl_c2w(camera_to_world(cam), path, "cam"),
    }
