"""The built-in head's procedural albedo, painted in its UV layout.

Every texel is traced back to a point of the neutral head (UV rasterization with
barycentrics), and the colour is a function of that 3D point: skin with slow tone
variation and a fine grain, redder cheeks, nose and ears, lips, eyebrows and short hair,
sclera with iris and pupil facing the eye's forward axis, a dark mouth cavity.
Deterministic: the only randomness is a seeded numpy Generator.
"""

from __future__ import annotations

import numpy as np

from ...uv.raster import rasterize
from .fields import bump, mirrored, smoothstep
from .mesh import ISLANDS, HeadMesh, eye_centres
from .sculpt import EAR_CENTRE, EYE_RADIUS, MOUTH_Y, vermilion

TEXTURE_SIZE = 1024
SEED = 20240607

SKIN = np.array([202, 150, 126]) / 255
CHEEK_RED = np.array([200, 112, 96]) / 255
LIP = np.array([160, 84, 80]) / 255
BROW = np.array([46, 32, 24]) / 255
HAIR = np.array([40, 29, 22]) / 255
LASH = np.array([30, 22, 18]) / 255
SCLERA = np.array([236, 230, 222]) / 255
IRIS = np.array([88, 112, 128]) / 255  # grey-blue
IRIS_INNER = np.array([128, 106, 70]) / 255  # a warm ring around the pupil
PUPIL = np.array([12, 10, 12]) / 255
MARGIN = np.array([196, 132, 118]) / 255
CAVITY = np.array([92, 34, 38]) / 255


def _noise(p, rng, wavelength, n_waves=12):
    """Smooth 3D noise in about [-1, 1]: a sum of random plane waves (evaluated at vertices
    and interpolated, so wavelengths should exceed the vertex spacing)."""
    dirs = rng.normal(size=(n_waves, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi, n_waves)
    arg = (p[:, None, :] * dirs).sum(-1) * (2 * np.pi / wavelength) + phase
    return np.cos(arg).sum(1) / np.sqrt(n_waves / 2)


def _mix(base, colour, amount):
    amount = np.clip(amount, 0.0, 1.0)[:, None]
    return base * (1 - amount) + colour * amount


def _hairline(p):
    """Height of the hairline around the head, by azimuth about the vertical axis."""
    azimuth = np.abs(np.arctan2(p[:, 0], p[:, 2]))
    knots = [0.0, 0.45, 0.75, 1.15, 1.32, 1.45, 1.62, 1.85, 2.2, np.pi]
    heights = [0.082, 0.079, 0.070, 0.042, 0.005, 0.035, 0.040, 0.012, -0.030, -0.050]
    return np.interp(azimuth, knots, heights)


def _streaks(rng, size, length, axis):
    """Texel noise in [0, 1] smeared over `length` texels along one image axis (wrapping):
    hair-like strands."""
    total = np.cumsum(rng.random((size, size)), axis=axis)
    first = (np.arange(size) < length).reshape((-1, 1) if axis == 0 else (1, -1))
    window = total - np.roll(total, length, axis=axis) + first * np.take(total, [-1], axis=axis)
    z = (window / length - 0.5) * np.sqrt(12 * length)  # about unit variance
    return np.clip(0.5 + 0.2 * z, 0, 1)


def _skin(t):
    p = t["p"]
    m = mirrored(p)
    colour = np.broadcast_to(SKIN, p.shape).copy()
    colour *= (1 + 0.035 * t["tone"] + 0.02 * t["mottle"])[:, None]
    colour = _mix(
        colour,
        CHEEK_RED,
        0.18 * bump(m, [0.045, -0.020, 0.068], [0.03, 0.03, 0.04])
        + 0.22 * bump(p, [0.0, -0.022, 0.110], [0.016, 0.016, 0.02])
        + 0.28 * bump(m, [0.085, 0.005, -0.012], [0.03, 0.04, 0.03]),
    )
    shade = 0.10 * bump(m, [0.031, 0.004, 0.075], [0.016, 0.008, 0.02])  # under the eyes
    lips = vermilion(p)
    shade += 0.4 * lips * (1 - smoothstep(np.abs(p[:, 1] - MOUTH_Y), 0.0003, 0.0012))  # slit
    facing_down = smoothstep(-t["normal"][:, 1], 0.3, 0.7)
    nostrils = bump(m, [0.0068, -0.0355, 0.099], [0.0045, 0.003, 0.0055])
    shade += 0.7 * smoothstep(nostrils, 0.05, 0.5) * facing_down
    colour = _mix(colour, LIP, lips) * (1 - np.clip(shade, 0, 1))[:, None]
    colour = _mix(colour, BROW, _brow_mask(p) * (0.65 + 0.35 * t["across"]))
    colour = _mix(colour, LASH, smoothstep(t["lashes"], 0.25, 0.85))
    hair = smoothstep(p[:, 1] - _hairline(p), -0.002, 0.006)
    hair *= 1 - smoothstep(bump(m, EAR_CENTRE, [0.016, 0.04, 0.03]), 0.0, 0.05)
    strands = 0.75 + 0.5 * t["down"]
    colour = _mix(colour, HAIR * strands[:, None], 0.97 * hair)
    return colour


def _lash_lines(head: HeadMesh) -> np.ndarray:
    """1 on the lid edges (strong on the upper lids, faint on the lower), 0 elsewhere; it
    fades over one ring of triangles once spread over the texels."""
    lashes = np.zeros(len(head.verts))
    for side in ("left", "right"):
        lashes[head.groups[f"eye_upper_{side}"][1:-1]] = 1.0
        lashes[head.groups[f"eye_lower_{side}"][1:-1]] = 0.45
    return lashes


def _brow_mask(p):
    m = mirrored(p)
    x = m[:, 0]
    t = (x - 0.012) / 0.042  # 0 at the inner end, 1 at the tail
    arch = 0.029 + 0.006 * np.sin(np.pi * np.clip(t, 0, 1) ** 0.8) - 0.004 * t
    half_height = 0.0056 * (1 - 0.5 * np.clip(t, 0, 1))
    mask = smoothstep(half_height - np.abs(m[:, 1] - arch), -0.0005, 0.0015)
    mask *= smoothstep(t, -0.05, 0.08) * smoothstep(1.05 - t, 0.0, 0.12)
    return mask * smoothstep(p[:, 2], 0.055, 0.07)


def _eyeball(t):
    p = t["p"]
    centres = eye_centres()
    local = p - np.where(p[:, :1] >= 0, centres[0], centres[1])
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    alpha = np.arccos(np.clip(local[:, 2], -1, 1))  # angle from the eye's forward axis
    beta = np.arctan2(local[:, 1], local[:, 0])
    iris_edge = np.arcsin(0.0058 / EYE_RADIUS)
    pupil_edge = 0.16
    colour = _mix(
        np.broadcast_to(SCLERA, p.shape),
        np.array([0.86, 0.66, 0.62]),
        0.5 * smoothstep(alpha, 0.9, 1.6),
    )
    fibres = 0.8 + 0.2 * np.cos(beta * 37 + 2 * np.cos(beta * 11)) * (0.6 + 0.8 * t["down"])
    iris = _mix(np.broadcast_to(IRIS, p.shape), IRIS_INNER, 1 - smoothstep(alpha, pupil_edge, 0.30))
    iris = (
        iris
        * fibres[:, None]
        * (1 - 0.55 * smoothstep(alpha, iris_edge - 0.08, iris_edge))[:, None]
    )
    colour = _mix(colour, iris, smoothstep(iris_edge + 0.02 - alpha, 0.0, 0.03))
    return _mix(colour, PUPIL, smoothstep(pupil_edge - alpha, -0.01, 0.01))


def paint_albedo(head: HeadMesh, size: int = TEXTURE_SIZE) -> np.ndarray:
    """The albedo (size, size, 3) uint8 for the head's UV layout; row 0 is v = 1."""
    rng = np.random.default_rng(SEED)
    table = rasterize(head.uv, head.uv_faces, size)
    covered, f = table.valid, table.face  # texels in row-major order, as covered[] lists them
    per_vertex = np.column_stack(
        [
            head.verts,
            vertex_normals(head),
            _noise(head.verts, rng, 0.05),
            _noise(head.verts, rng, 0.015),
            _lash_lines(head),
        ]
    )
    at_texels = np.einsum("tkc,tk->tc", per_vertex[head.faces[f]], table.bary)
    texels = {
        "p": at_texels[:, :3],
        "normal": at_texels[:, 3:6],
        "tone": at_texels[:, 6],
        "mottle": at_texels[:, 7],
        "lashes": at_texels[:, 8],
        "down": _streaks(rng, size, 9, axis=0)[covered],
        "across": _streaks(rng, size, 5, axis=1)[covered],
    }
    island = head.face_island[f]
    painters = {
        "skin": _skin,
        "eyeball": _eyeball,
        "lid_margin": lambda t: np.broadcast_to(MARGIN, t["p"].shape),
        "mouth_cavity": lambda t: _mix(
            np.broadcast_to(CAVITY, t["p"].shape),
            CAVITY * 0.4,
            smoothstep(0.085 - t["p"][:, 2], 0.0, 0.03),
        ),
    }
    colour = np.zeros((len(f), 3))
    for name, paint in painters.items():
        sel = island == ISLANDS.index(name)
        colour[sel] = paint({k: v[sel] for k, v in texels.items()})
    colour *= 1 + 0.015 * rng.standard_normal(len(f))[:, None]  # texel grain
    image = np.zeros((size, size, 3), np.float32)
    image[covered] = colour
    image = _dilate(image, covered, 4)
    return np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)


def vertex_normals(head: HeadMesh) -> np.ndarray:
    """Area-weighted unit vertex normals (V,3)."""
    v, f = head.verts, head.faces
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], face_n)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def _dilate(image, filled, steps):
    """Grow the painted islands outward a few texels, so filtering at edges finds colour."""
    for _ in range(steps):
        acc = np.zeros_like(image)
        n = np.zeros(filled.shape)
        for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            acc += np.roll(image * filled[..., None], (dr, dc), (0, 1))
            n += np.roll(filled, (dr, dc), (0, 1))
        grow = ~filled & (n > 0)
        image[grow] = acc[grow] / n[grow][:, None]
        filled = filled | grow
    return image
