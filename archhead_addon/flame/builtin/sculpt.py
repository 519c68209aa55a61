"""The head's shape as an implicit surface, and rays from inside the head that find it.

The skin is the zero level set of a sculpt function built from ellipsoids, round cones and
spheres joined with smooth minima (cranium, midface, jaw, chin, neck, cheeks, brow, nose,
lips, eyelids, ears). It is a shape function, not an exact distance; only its sign and
continuity matter, since vertices are placed by bisection along rays from `RAY_ORIGIN`.
Units are metres; y up, the face looks toward +z, the subject's left is +x.
"""

from __future__ import annotations

import numpy as np

from .fields import mirrored, smoothstep

RAY_ORIGIN = np.array([0.0, -0.01, 0.0])
EYE_CENTRE = np.array([0.0315, 0.014, 0.064])  # left eye; the right one mirrors x
EYE_RADIUS = 0.0125
LID_GAP = 0.0016  # lid skin floats this far above the eyeball
MOUTH_Y, MOUTH_Z = -0.058, 0.096  # the slit where the lips meet
NECK_BOTTOM = -0.19
EAR_CENTRE = np.array([0.078, 0.005, -0.014])  # left ear


def _ellipsoid(p, centre, radii):
    """Inigo Quilez's distance bound for an ellipsoid (exact on the surface)."""
    q = (p - np.asarray(centre)) / radii
    k0 = np.sqrt((q * q).sum(-1))
    k1 = np.sqrt(((q / radii) ** 2).sum(-1))
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def _round_cone(p, a, b, ra, rb):
    """A capsule from a to b whose radius goes linearly from ra to rb."""
    a, b = np.asarray(a), np.asarray(b)
    ab = b - a
    t = np.clip(((p - a) * ab).sum(-1) / (ab * ab).sum(), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.sqrt(((p - closest) ** 2).sum(-1)) - (ra + (rb - ra) * t)


def _lip(p, thin, centre, radii):
    """An ellipsoid whose height and depth shrink by `thin` (per point) toward the corners."""
    q = p - np.asarray(centre)
    q = np.stack([q[..., 0], q[..., 1] / thin, q[..., 2] / thin], -1)
    return _ellipsoid(q, np.zeros(3), np.asarray(radii))


def _smin(a, b, k):
    """Smooth union: the minimum with a rounded fillet of size k."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def _smax(a, b, k):
    return -_smin(-a, -b, k)


def _rot_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


_EAR_FRAME = _rot_x(-0.22) @ _rot_y(-0.35)  # the pinna leans back and opens forward


def head_sdf(p: np.ndarray) -> np.ndarray:
    """The sculpt function at points p (..., 3): negative inside the head."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    m = mirrored(p)  # paired features are written for the left side
    ell = _ellipsoid

    # cranium, a little narrower at the temples than over the ears
    temples = 1.0 - 0.07 * smoothstep(z, -0.02, 0.09)
    d = ell(np.stack([x / temples, y, z], -1), [0, 0.034, -0.010], [0.077, 0.097, 0.099])
    # midface; jaw narrowing toward the chin; the dental arch under the lips; the chin
    d = _smin(d, ell(p, [0, -0.012, 0.030], [0.063, 0.060, 0.062]), 0.02)
    chin_taper = 1.0 - 0.32 * smoothstep(z, -0.01, 0.085)
    d = _smin(
        d,
        ell(np.stack([x / chin_taper, y, z], -1), [0, -0.059, 0.012], [0.053, 0.040, 0.068]),
        0.018,
    )
    d = _smin(d, ell(p, [0, -0.060, 0.061], [0.034, 0.030, 0.034]), 0.015)
    d = _smin(d, ell(p, [0, -0.087, 0.075], [0.021, 0.016, 0.017]), 0.012)
    # neck: an elliptic cylinder whose base sits a little further back, rounded at the bottom
    nz = z + 0.018 - 0.12 * (y + 0.05)
    neck = np.sqrt((x / 0.053) ** 2 + (nz / 0.050) ** 2) * 0.051 - 0.051
    neck = _smax(_smax(neck, NECK_BOTTOM - y, 0.02), y, 0.02)
    d = _smin(d, neck, 0.014)
    # cheekbones, cheeks, brow ridge
    d = _smin(d, ell(m, [0.050, 0.002, 0.052], [0.020, 0.012, 0.022]), 0.02)
    d = _smin(d, ell(m, [0.034, -0.032, 0.056], [0.022, 0.025, 0.025]), 0.016)
    d = _smin(d, ell(p, [0, 0.037, 0.075], [0.048, 0.012, 0.0165]), 0.014)
    # eye sockets, then the eyelids as a shell over each eyeball
    d = _smax(d, -ell(m, [0.031, 0.015, 0.089], [0.019, 0.013, 0.013]), 0.006)
    lids = np.sqrt(((m - EYE_CENTRE) ** 2).sum(-1)) - (EYE_RADIUS + LID_GAP)
    d = _smin(d, lids, 0.004)
    # nose: bridge, body, tip, wings; nostrils pressed in underneath
    d = _smin(d, _round_cone(p, [0, 0.024, 0.087], [0, -0.017, 0.107], 0.0058, 0.0078), 0.006)
    d = _smin(d, ell(p, [0, -0.012, 0.091], [0.013, 0.024, 0.015]), 0.006)
    d = _smin(d, ell(p, [0, -0.023, 0.106], [0.0095, 0.0085, 0.0095]), 0.005)
    d = _smin(d, ell(m, [0.0125, -0.028, 0.097], [0.0065, 0.0058, 0.0068]), 0.004)
    d = _smax(d, -ell(m, [0.0065, -0.0345, 0.101], [0.0035, 0.002, 0.005]), 0.002)
    # the skin of the upper lip; the lips, thinner toward the corners, meeting in a groove
    d = _smin(d, ell(p, [0, -0.041, 0.085], [0.022, 0.012, 0.0125]), 0.008)
    thin = 1.0 - 0.45 * smoothstep(np.abs(x), 0.006, 0.026)
    d = _smin(d, _lip(p, thin, [0, -0.0512, 0.0915], [0.025, 0.0068, 0.009]), 0.006)
    d = _smin(d, _lip(p, thin, [0, -0.0655, 0.0895], [0.022, 0.0075, 0.0072]), 0.009)
    groove = _round_cone(p, [-0.026, MOUTH_Y, MOUTH_Z], [0.026, MOUTH_Y, MOUTH_Z], 0.0022, 0.0022)
    d = _smax(d, -groove, 0.0015)
    return _smin(d, _ear(m), 0.004)


def _ear(m):
    """A pinna on the left side (m = mirrored points): an egg-shaped plate, wider at the top,
    with a rolled rim (helix), a bowl (concha) and a lobe."""
    e = np.einsum("...c,cr->...r", m - EAR_CENTRE, _EAR_FRAME)  # x out, y up, z forward
    ex, ey, ez = e[..., 0], e[..., 1], e[..., 2]
    widen = 1.0 + 0.22 * np.clip(ey / 0.03, -1, 1)
    plate = _ellipsoid(np.stack([ex, ey, ez / widen], -1), np.zeros(3), [0.0075, 0.031, 0.0175])
    ring = np.sqrt((ey / 0.0275) ** 2 + (ez / (0.0150 * widen)) ** 2)
    rim = np.sqrt(((ring - 1.0) * 0.02) ** 2 + (ex - 0.0035) ** 2) - 0.0026
    pinna = _smin(plate, rim, 0.002)
    pinna = _smax(pinna, -_ellipsoid(e, [0.0105, -0.003, 0.002], [0.0075, 0.012, 0.0085]), 0.0025)
    lobe = _ellipsoid(e, [0.001, -0.028, 0.004], [0.005, 0.0085, 0.0075])
    return _smin(pinna, lobe, 0.003)


def project_rays(directions: np.ndarray, reach=0.26, min_step=0.001) -> np.ndarray:
    """The outermost skin point along each unit direction from RAY_ORIGIN, (n, 3).

    Steps inward from `reach` by half the sculpt value, never by less than `min_step`
    (thinner than any feature, so none is stepped over), until inside; then bisects the
    last step.
    """
    s = np.full(len(directions), float(reach))
    prev = s.copy()
    todo = np.arange(len(directions))
    while len(todo):
        d = head_sdf(RAY_ORIGIN + s[todo, None] * directions[todo])
        outside = d >= 0
        todo, d = todo[outside], d[outside]
        prev[todo] = s[todo]
        s[todo] -= np.maximum(0.5 * d, min_step)
        if (s[todo] <= 0).any():
            raise RuntimeError("a ray from inside the head found no skin")
    lo, hi = s, prev  # lo inside, hi outside
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        inner = head_sdf(RAY_ORIGIN + mid[:, None] * directions) < 0
        lo, hi = np.where(inner, mid, lo), np.where(inner, hi, mid)
    return RAY_ORIGIN + (0.5 * (lo + hi))[:, None] * directions


def vermilion(p):
    """Where the lips are red, 0..1: from the slit up to a bowed line and down to a curve."""
    x, dy = np.abs(p[:, 0]), p[:, 1] - MOUTH_Y
    across = np.sqrt(np.clip(1 - (x / 0.0255) ** 2, 0, 1))
    bow = 0.0012 * np.exp(-(((x - 0.0055) / 0.004) ** 2)) - 0.0010 * np.exp(-((x / 0.0025) ** 2))
    upper = 0.0078 * across**0.6 + bow
    lower = 0.0095 * across**0.7
    inside = np.where(dy >= 0, upper - dy, lower + dy)
    front = smoothstep(p[:, 2], 0.070, 0.080)
    return smoothstep(inside, -0.0004, 0.0008) * front
