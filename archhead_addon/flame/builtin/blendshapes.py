"""Identity and expression bases of the built-in head, FLAME-style (coefficients in sigmas).

The leading components have names (IDENTITY_NAMES, EXPRESSION_NAMES, in this order); the
rest are smooth random fields whose size decays like a PCA spectrum. Every field is a
function of position, so vertices that coincide (the closed lips) move together; only the
jaw-open shape, which uses the jaw weights, parts them. Eyeballs only translate (by the
field at their centre) under identity and do not move under expressions; the blinks come
from closing the lids of the sculpt over the eyeball.
"""

from __future__ import annotations

import numpy as np

from ...rotations import axis_angle_to_matrix
from .fields import bump, mirrored, random_smooth_fields, side, smoothstep
from .mesh import HeadMesh, eye_centres
from .sculpt import MOUTH_Y

N_IDENTITY, N_EXPRESSION = 300, 100
IDENTITY_NAMES = (
    "head_width",
    "face_length",
    "head_depth",
    "nose_size",
    "jaw_width",
    "cheekbones",
    "chin_projection",
    "brow_ridge",
    "eye_spacing",
    "lip_fullness",
    "nose_bridge",
    "ear_size",
    "neck_thickness",
)
EXPRESSION_NAMES = (
    "jaw_open",
    "smile",
    "brow_raise",
    "blink_left",
    "blink_right",
    "pucker",
    "frown",
    "cheek_puff",
    "lip_press",
    "sneer",
)
IDENTITY_SEED, EXPRESSION_SEED = 1301, 1302
NAMED_IDENTITY_MM = 3.5  # largest displacement of identity component 0 at one sigma
RANDOM_IDENTITY_MM = 2.0  # RMS of identity component 0's random continuation at one sigma
RANDOM_EXPRESSION_MM = 10.0  # largest displacement of expression 0's continuation


def _unit_max(field):
    return field / np.abs(field).max()


def _named_identity(p: np.ndarray) -> list[np.ndarray]:
    """Unit-peak fields, in IDENTITY_NAMES order, evaluated at points p (V,3)."""
    m, s = mirrored(p), side(p)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    zero = np.zeros_like(x)
    above_neck = smoothstep(y, -0.16, -0.08)
    lower_face = smoothstep(-y, 0.0, 0.1) * smoothstep(z, -0.02, 0.05)
    nose = bump(p, [0.0, -0.012, 0.100], [0.024, 0.042, 0.035])[:, None]
    cheekbone = bump(m, [0.052, 0.0, 0.055], [0.03, 0.02, 0.03])[:, None]
    ear = bump(m, [0.08, 0.0, -0.01], [0.025, 0.045, 0.035])[:, None]
    ear_root = s * [0.072, 0.0, 0.0] + [0.0, 0.0, -0.01]
    fields = [
        np.stack([x * above_neck, zero, zero], 1),  # head width: scale x
        np.stack([zero, -lower_face, zero], 1),  # face length: the lower face moves down
        np.stack([zero, zero, (z + 0.01) * above_neck], 1),  # head depth: scale z
        (p - [0.0, -0.030, 0.090]) * nose,  # nose size: scale about the nose's base
        np.stack([x * bump(m, [0.045, -0.075, 0.02], [0.04, 0.04, 0.06]), zero, zero], 1),
        (s * [0.6, 0.0, 0.0] + [0.0, 0.0, 0.8]) * cheekbone,  # cheekbones: out and forward
        [0.0, -0.3, 1.0] * bump(p, [0.0, -0.092, 0.08], [0.03, 0.025, 0.03])[:, None],  # chin
        [0.0, 0.0, 1.0] * bump(m, [0.025, 0.04, 0.085], [0.04, 0.018, 0.03])[:, None],  # brow
        s * [1.0, 0.0, 0.0] * _flat_top(m, eye_centres()[0], 0.016, 0.032)[:, None],  # eyes
        _lip_fullness(p),
        [0.0, 0.0, 1.0] * bump(p, [0.0, 0.005, 0.095], [0.012, 0.03, 0.03])[:, None],  # bridge
        (p - ear_root) * ear,  # ear size: scale about where the ear joins the head
        np.stack([x, zero, z + 0.02], 1) * smoothstep(-y, 0.06, 0.11)[:, None],  # neck
    ]
    return [_unit_max(f) for f in fields]


def _flat_top(p, centre, inner, outer):
    """1 within `inner` of the centre, falling smoothly to 0 at `outer`."""
    d = np.linalg.norm(p - centre, axis=1)
    return 1 - smoothstep(d, inner, outer)


def _lip_mask(p):
    return bump(p, [0.0, MOUTH_Y, 0.09], [0.032, 0.02, 0.025])


def _lip_fullness(p):
    lips = _lip_mask(p)
    return np.stack([np.zeros(len(p)), (p[:, 1] - MOUTH_Y) * 30 * lips, lips], 1)


def _eyes_at_centres(head: HeadMesh) -> np.ndarray:
    """Vertex positions with each eyeball collapsed to its centre (so fields move it rigidly)."""
    p = head.verts.copy()
    for side_name, centre in zip(("left", "right"), eye_centres(), strict=True):
        p[head.groups[f"eyeball_{side_name}"]] = centre
    return p


def identity_basis(head: HeadMesh) -> np.ndarray:
    """(V, 3, 300): named components scaled by NAMED_IDENTITY_MM / sqrt(1+k), then random
    symmetric smooth fields with RMS RANDOM_IDENTITY_MM / (1+k), shortening wavelengths."""
    p = _eyes_at_centres(head)
    named = _named_identity(p)
    k = np.arange(N_IDENTITY)
    basis = np.empty((len(p), 3, N_IDENTITY))
    for i, f in enumerate(named):
        basis[:, :, i] = f * NAMED_IDENTITY_MM * 1e-3 / np.sqrt(1 + i)
    rest = k[len(named) :]
    wavelengths = 0.30 / (1 + rest / 40)
    fields = random_smooth_fields(p, len(rest), IDENTITY_SEED, wavelengths, symmetric=True)
    basis[:, :, len(named) :] = fields * (RANDOM_IDENTITY_MM * 1e-3 / (1 + rest))
    return basis


def _named_expressions(head: HeadMesh, jaw_weight, jaw_joint, blinks) -> list[np.ndarray]:
    """Displacements for EXPRESSION_NAMES (at coefficient 1), in that order."""
    p = head.verts
    m, s = mirrored(p), side(p)
    x, y = p[:, 0], p[:, 1]
    zero = np.zeros_like(x)
    col = lambda a: a[:, None]  # noqa: E731

    # jaw open: the skin of a 0.11 rad jaw rotation, and the upper lip lifting off the teeth
    rot = axis_angle_to_matrix(np.array([0.11, 0.0, 0.0]))
    opened = np.einsum("rc,vc->vr", rot, p - jaw_joint) + jaw_joint
    upper_lip = bump(p, [0.0, MOUTH_Y + 0.006, 0.09], [0.03, 0.012, 0.03]) * (1 - jaw_weight)
    jaw_open = col(jaw_weight) * (opened - p) + col(upper_lip) * [0.0, 0.0035, 0.0]

    corners = bump(m, [0.026, MOUTH_Y, 0.085], [0.020, 0.017, 0.022])
    cheeks = bump(m, [0.036, -0.028, 0.070], [0.026, 0.024, 0.03])
    under_eye = bump(m, [0.031, 0.004, 0.076], [0.016, 0.008, 0.02])
    smile = (
        col(corners) * s * [0.005, 0.0, 0.0]
        + col(corners) * [0.0, 0.0065, -0.004]
        + col(cheeks) * [0.0, 0.004, 0.0025]
        + col(under_eye) * [0.0, 0.0015, 0.0]
    )

    brows = bump(m, [0.030, 0.042, 0.080], [0.035, 0.025, 0.04])
    forehead = bump(p, [0.0, 0.07, 0.07], [0.06, 0.04, 0.05])
    brow_raise = col(brows) * [0.0, 0.005, 0.0005] + col(forehead) * [0.0, 0.002, 0.0]

    lips = _lip_mask(p)
    pucker = np.stack([-0.45 * x * lips, zero, 0.009 * lips], 1)

    inner_brows = bump(m, [0.022, 0.036, 0.085], [0.026, 0.02, 0.03])
    frown = (
        col(inner_brows) * s * [-0.002, 0.0, 0.0]
        + col(inner_brows) * [0.0, -0.003, 0.0005]
        + col(corners) * [0.0, -0.003, 0.0]
    )

    puff_centre = np.array([0.0, -0.045, 0.0])
    outward = p - puff_centre
    outward /= np.linalg.norm(outward, axis=1, keepdims=True)
    cheek_puff = col(bump(m, [0.040, -0.048, 0.062], [0.026, 0.026, 0.032])) * outward * 0.006

    lip_press = np.stack([zero, -0.35 * (y - MOUTH_Y) * lips, -0.0025 * lips], 1)

    sneer = col(bump(m, [0.012, -0.046, 0.095], [0.016, 0.012, 0.02])) * [0.0, 0.003, 0.0] + col(
        bump(m, [0.0135, -0.028, 0.097], [0.012, 0.01, 0.012])
    ) * [0.0, 0.002, 0.0]
    return [
        jaw_open,
        smile,
        brow_raise,
        blinks[0],
        blinks[1],
        pucker,
        frown,
        cheek_puff,
        lip_press,
        sneer,
    ]


def expression_basis(head: HeadMesh, jaw_weight, jaw_joint, blinks) -> np.ndarray:
    """(V, 3, 100): the named expressions, then random smooth fields on the face whose
    largest displacement is RANDOM_EXPRESSION_MM / (1+k). Zero on the eyeballs."""
    p = head.verts
    named = _named_expressions(head, jaw_weight, jaw_joint, blinks)
    basis = np.empty((len(p), 3, N_EXPRESSION))
    for i, f in enumerate(named):
        basis[:, :, i] = f
    rest = np.arange(len(named), N_EXPRESSION)
    face = (
        smoothstep(p[:, 2], 0.02, 0.07)
        * smoothstep(p[:, 1], -0.12, -0.09)
        * (1 - smoothstep(p[:, 1], 0.06, 0.09))
    )
    near_eyes = sum(bump(p, c + [0, 0, 0.01], [0.022, 0.016, 0.02]) for c in eye_centres())
    mask = face * (1 - 0.8 * np.clip(near_eyes, 0, 1))
    fields = (
        random_smooth_fields(p, len(rest), EXPRESSION_SEED, 0.12 / (1 + rest / 30), symmetric=False)
        * mask[:, None, None]
    )
    peak = np.abs(fields).max(axis=(0, 1))
    basis[:, :, len(named) :] = fields * (RANDOM_EXPRESSION_MM * 1e-3 / (1 + rest) / peak)
    for side_name in ("left", "right"):
        basis[head.groups[f"eyeball_{side_name}"]] = 0.0
    return basis
