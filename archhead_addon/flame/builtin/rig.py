"""The built-in head's rig: joint regressor, skinning weights and pose correctives.

Joints follow FLAME: 0 global (mid-neck), 1 neck (top of the neck), 2 jaw (between the
jaw hinges, in front of the ears), 3 left eye, 4 right eye (the eyeball centres).
"""

from __future__ import annotations

import numpy as np

from .fields import bump, mirrored, smoothstep
from .mesh import MOUTH_HALF_WIDTH, HeadMesh, eye_centres
from .sculpt import MOUTH_Y, MOUTH_Z

JOINT_TARGETS = np.array(
    [
        [0.0, -0.110, -0.026],  # global: the middle of the neck
        [0.0, -0.050, -0.022],  # neck: its top, under the skull
        [0.0, -0.008, 0.012],  # jaw: the axis through both jaw hinges
    ]
)
ROOT_BLEND = (-0.085, -0.150)  # the neck blends from the neck joint to the root between these y


def _project_simplex(w):
    """Euclidean projection of each row onto the probability simplex (sort-based)."""
    s = -np.sort(-w, axis=-1)
    cum = np.cumsum(s, axis=-1) - 1
    k = np.arange(1, w.shape[-1] + 1)
    rho = (s - cum / k > 0).sum(-1, keepdims=True)
    tau = np.take_along_axis(cum, rho - 1, axis=-1) / rho
    return np.maximum(w - tau, 0)


def convex_weights(
    points: np.ndarray, target: np.ndarray, spread: float = 1e-7, iterations: int = 2000
) -> np.ndarray:
    """Weights on the simplex whose combination of `points` (n,3) lands on `target`.

    Projected gradient on |w P - target|^2 + spread |w|^2; the small second term spreads
    the weight over many points instead of a few.
    """
    n = len(points)
    w = np.full(n, 1.0 / n)
    step = 0.5 / ((points * points).sum() + spread)
    for _ in range(iterations):
        residual = (w[:, None] * points).sum(0) - target
        grad = 2 * (points * residual).sum(1) + 2 * spread * w
        w = _project_simplex(w - step * grad)
    return w


def joint_regressor(head: HeadMesh) -> np.ndarray:
    """(5, V): each row a convex combination of vertices."""
    v = head.verts
    reg = np.zeros((5, len(v)))
    skin = np.ones(len(v), bool)
    for name in (
        "eyeball_left",
        "eyeball_right",
        "mouth_cavity_rings",
        "mouth_cavity_centre",
        "lid_margin_left",
        "lid_margin_right",
    ):
        skin[head.groups[name].ravel()] = False
    for j, target in enumerate(JOINT_TARGETS):
        if j == 2:  # skin over both jaw hinges
            near = bump(mirrored(v), [0.068, target[1], target[2]], [0.012, 0.012, 0.012]) > 0
        else:  # a band around the neck at the joint's height
            near = (np.abs(v[:, 1] - target[1]) < 0.008) & (v[:, 2] < 0.03)
        idx = np.flatnonzero(near & skin)
        reg[j, idx] = convex_weights(v[idx], target)
    for j, side in ((3, "left"), (4, "right")):
        ring = head.groups[f"eyeball_equator_{side}"]
        reg[j, ring] = 1.0 / len(ring)
    return reg


def jaw_weight(head: HeadMesh, jaw: np.ndarray) -> np.ndarray:
    """How much each vertex follows the jaw: chin, lower lip, lower cheeks, under the chin."""
    v = head.verts
    below = np.arctan2(-(v[:, 1] - jaw[1]), v[:, 2] - jaw[2])  # angle below the jaw's forward
    mouth_angle = np.arctan2(-(MOUTH_Y - jaw[1]), MOUTH_Z - jaw[2])
    w = smoothstep(below, mouth_angle - 0.10, mouth_angle + 0.08)
    w *= smoothstep(v[:, 2], -0.012, 0.018)  # nothing behind the jaw's back edge
    border = -0.083 - 0.02 * smoothstep(v[:, 2], 0.0, 0.07)  # the jaw's lower edge
    w *= 1 - smoothstep(border - v[:, 1], 0.004, 0.03)  # fading down the throat
    # at the lips the slit decides: toward it the upper lip goes to 0, the lower lip to 1
    # (1 along the slit, fading to 0 at the corners, where both lips meet the cheeks)
    along = np.sqrt(np.clip(1 - (v[:, 0] / MOUTH_HALF_WIDTH) ** 2, 0, 1))
    near = (
        (1 - smoothstep(np.abs(v[:, 1] - MOUTH_Y), 0.002, 0.014))
        * along
        * smoothstep(v[:, 2], 0.06, 0.08)
    )
    upper_ring, lower_ring = head.groups["lip_ring_upper"], head.groups["lip_ring_lower"]
    lower = v[:, 1] < MOUTH_Y
    lower[lower_ring] = True
    w = np.where(lower, w + (1 - w) * near, w * (1 - near))
    w[upper_ring], w[lower_ring] = 0.0, 1.0
    w[upper_ring[[0, -1]]] = 0.5  # the corners
    rings = head.groups["mouth_cavity_rings"]
    n_up = len(head.groups["lip_ring_upper"])
    w[rings[:, :n_up].ravel()] = 0.0
    w[rings[:, n_up:].ravel()] = 1.0
    w[rings[:, [0, n_up - 1]].ravel()] = 0.5
    w[head.groups["mouth_cavity_centre"]] = 0.5
    for side in ("left", "right"):
        w[head.groups[f"lid_margin_{side}"]] = 0.0
    return w


def skinning_weights(head: HeadMesh, joints: np.ndarray) -> np.ndarray:
    """(V, 5) rows summing to 1."""
    v = head.verts
    jaw = jaw_weight(head, joints[2])
    root = smoothstep(-v[:, 1], -ROOT_BLEND[0], -ROOT_BLEND[1])
    weights = np.stack(
        [root * (1 - jaw), (1 - root) * (1 - jaw), jaw, np.zeros(len(v)), np.zeros(len(v))], 1
    )
    for j, side in ((3, "left"), (4, "right")):
        eye = head.groups[f"eyeball_{side}"]
        weights[eye] = 0.0
        weights[eye, j] = 1.0
    return weights


def _feature(joint: int, row: int, col: int) -> int:
    """Column of posedirs for entry (row, col) of (R - I) of `joint` (1..4)."""
    return (joint - 1) * 9 + 3 * row + col


def pose_correctives(head: HeadMesh, joints: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(V, 3, 36) offsets per entry of (R_j - I), j = neck, jaw, eyes (FLAME's layout).

    - neck and jaw: the blend zone between two joints loses volume as they rotate apart
      (LBS's candy wrapper); it is pushed back out in proportion to 1 - cos(angle), which is
      -trace(R - I) / 2, so it goes on the three diagonal entries;
    - neck pitch (sin on entry (2,1)): the throat bulges when the chin drops, the nape
      flattens, and the reverse when the head tips back;
    - jaw opening: the soft tissue under the chin bunches outward;
    - eyes: the lids follow the gaze up and down (and a little sideways).
    Eyeballs get none.
    """
    v = head.verts
    out = np.zeros((len(v), 3, 36))
    for joint, blend, axis_point in ((1, weights[:, 0], joints[1]), (2, weights[:, 2], joints[2])):
        radial = v - axis_point
        radial[:, 0] *= 1.0 if joint == 1 else 0.0  # the jaw turns about x: radial in y-z
        if joint == 1:
            radial[:, 1] = 0.0  # the neck's cross-section is horizontal
        dist = np.linalg.norm(radial, axis=1, keepdims=True)
        outward = radial / np.maximum(dist, 1e-9)
        zone = blend * (1 - blend)
        per_entry = -0.5 * dist * zone[:, None] * outward  # times (R_dd - 1), summed over d
        for d in range(3):
            out[:, :, _feature(joint, d, d)] = per_entry
    throat = bump(v, [0.0, -0.112, 0.040], [0.04, 0.03, 0.03])
    nape = bump(v, [0.0, -0.085, -0.075], [0.05, 0.035, 0.03])
    out[:, :, _feature(1, 2, 1)] = throat[:, None] * [0.0, -0.002, 0.006] + nape[:, None] * [
        0.0,
        0.0,
        0.004,
    ]
    under_chin = bump(v, [0.0, -0.100, 0.055], [0.03, 0.018, 0.03])
    out[:, :, _feature(2, 2, 1)] = under_chin[:, None] * [0.0, -0.004, 0.002]
    for joint, centre in ((3, eye_centres()[0]), (4, eye_centres()[1])):
        lids = bump(v, centre + [0, 0, 0.008], [0.02, 0.016, 0.02])
        upper = lids * smoothstep(v[:, 1] - centre[1], -0.001, 0.003)
        lower = lids - upper
        out[:, :, _feature(joint, 2, 1)] = upper[:, None] * [0.0, -0.006, 0.0] + lower[:, None] * [
            0.0,
            -0.003,
            0.0,
        ]
        out[:, :, _feature(joint, 0, 2)] = lids[:, None] * [0.002, 0.0, 0.0]
    for side in ("left", "right"):
        out[head.groups[f"eyeball_{side}"]] = 0.0
    return out
