"""The built-in head's mesh: topology, neutral geometry and UV layout.

The skin is one latitude-longitude grid around the head (poles at the neck bottom and the
crown, the seam at the back), placed on the sculpt by rays from inside the head. Its
parameter lines are warped so the face gets most of the vertices: denser columns in front,
denser rows from chin to brow, and magnifying lenses over the eyes and the mouth. Each eye
and the mouth is a slit cut along a grid row (the row's vertices are doubled), so the
lids and the lips are separate surfaces; the eye slits are opened into almond shapes by
pushing the rows apart. Behind the slits: a lid margin tucked into each eyeball and a
mouth cavity. Eyeballs are separate closed spheres.

UV layout: the skin grid fills v in [0.16, 1] (u around the head, the face in the middle);
the strip below holds the eyeball discs, the mouth cavity and the lid margins, and leaves
u > 0.67 free for teeth. Image rows of the albedo run down in v (row 0 is v = 1).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .fields import smoothstep
from .sculpt import (
    EAR_CENTRE,
    EYE_CENTRE,
    EYE_RADIUS,
    LID_GAP,
    MOUTH_Y,
    MOUTH_Z,
    RAY_ORIGIN,
    project_rays,
)

N_COLS = 96  # grid columns around the head (even: one column on the midline in front)
N_ROWS = 50  # grid rows between the two poles
SKIN_V0 = 0.16  # the skin grid's lowest v

# the eye opening, in radians of elevation
EYE_OPEN_UP, EYE_OPEN_DOWN = 0.080, 0.042  # how far the lid edges part from the slit
EYE_CLOSE_AT = 0.35  # closed lids meet this fraction of EYE_OPEN_DOWN below the slit
EYE_FALLOFF_UP, EYE_FALLOFF_DOWN = 0.085, 0.055
EYE_HALF_WIDTH = (0.0140, 0.0125)  # inner and outer corner, metres from the eye centre in x
MOUTH_HALF_WIDTH = 0.0245
LENSES = (  # (centre, half-sizes in radians, strength), applied in this order
    ("ear_right", (0.22, 0.24), 0.5),
    ("ear_left", (0.22, 0.24), 0.5),
    ("mouth", (0.30, 0.13), 0.45),
    ("eye_right", (0.16, 0.11), 0.45),
    ("eye_left", (0.16, 0.11), 0.45),
)
EYEBALL_RINGS = np.array(
    [0.13, 0.26, 0.38, 0.50, 0.64, 0.82, 1.02, 1.25, np.pi / 2, 1.98, 2.42, 2.84]
)  # polar angles from the front; one exactly at 90 deg
EYEBALL_SEGMENTS = 20
CORNEA_BULGE = 0.0007
CAVITY_RINGS = ((0.002, 0.45), (0.006, 0.95), (0.018, 1.0), (0.034, 0.55))  # depth, height
CAVITY_HEIGHT = 0.012  # half height of the mouth cavity at its widest
MARGIN_DEPTH = 0.001  # lid margins end this far inside the eyeball


ISLANDS = ("skin", "eyeball", "lid_margin", "mouth_cavity")  # UV islands, by what they cover


@dataclass(frozen=True)
class HeadMesh:
    verts: np.ndarray  # (V,3) metres
    faces: np.ndarray  # (F,3) wound counter-clockwise seen from outside
    uv: np.ndarray  # (Vt,2)
    uv_faces: np.ndarray  # (F,3)
    face_island: np.ndarray  # (F,) index into ISLANDS
    groups: dict  # name -> vertex indices (see `_Topology`)


def _inverse_cdf(density, lo, hi, t):
    """Positions in [lo, hi] whose share of the integral of `density` is t."""
    x = np.linspace(lo, hi, 4097)
    w = density(x)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]))])
    return np.interp(t * cdf[-1], cdf, x)


def _azimuths() -> np.ndarray:
    """Column azimuths, 0 in front (+z), positive toward +x, mirror-symmetric, -pi at the back."""

    def density(a):
        return 0.40 + 1.9 * np.exp(-((a / 0.62) ** 2)) + 0.45 * np.exp(-(((a - 1.62) / 0.32) ** 2))

    half = _inverse_cdf(density, 0.0, np.pi, np.arange(N_COLS // 2 + 1) / (N_COLS // 2))
    return np.concatenate([-half[::-1], half[1:-1]])  # columns 0 (back) .. N-1


def _elevation(point) -> float:
    d = np.asarray(point) - RAY_ORIGIN
    return float(np.arctan2(d[1], np.hypot(d[0], d[2])))


def _azimuth(point) -> float:
    d = np.asarray(point) - RAY_ORIGIN
    return float(np.arctan2(d[0], d[2]))


def _eye_slit_point():
    """Where the closed lids of the left eye would meet: a little below the pupil."""
    return EYE_CENTRE + np.array([0.0, -0.0012, EYE_RADIUS + LID_GAP])


def _row_elevations() -> tuple[np.ndarray, int, int]:
    """Row elevations (bottom to top) and the eye and mouth slit rows (1-based)."""

    def density(a):
        return (
            0.28
            + 1.6 * np.exp(-(((a + 0.2) / 0.55) ** 4))
            + 0.7 * np.exp(-(((a + 1.05) / 0.25) ** 2))
            + 0.25 * smoothstep(a, 0.4, 0.8)
        )

    t = np.arange(1, N_ROWS + 1) / (N_ROWS + 1)
    rows = _inverse_cdf(density, -np.pi / 2, np.pi / 2, t)
    eye_target = _elevation(_eye_slit_point())
    mouth_target = _elevation([0.0, MOUTH_Y, MOUTH_Z])
    j_eye = int(np.abs(rows - eye_target).argmin())
    j_mouth = int(np.abs(rows - mouth_target).argmin())
    # a monotone piecewise-linear nudge puts the two slit rows exactly on their targets
    src = [-np.pi / 2, rows[j_mouth], rows[j_eye], np.pi / 2]
    dst = [-np.pi / 2, mouth_target, eye_target, np.pi / 2]
    return np.interp(rows, src, dst), j_eye + 1, j_mouth + 1


def _lens(theta, phi, centre, half, strength):
    """Pull parameter lines toward a centre: more vertices there, none folded."""
    dt, dp = theta - centre[0], phi - centre[1]
    factor = 1.0 - strength * np.exp(-((dt / half[0]) ** 2 + (dp / half[1]) ** 2))
    return centre[0] + dt * factor, centre[1] + dp * factor


class _Topology:
    """Vertex indices, faces and UVs; geometry comes later from `build_head`.

    Groups (`_left` / `_right` for each eye): `eyeball`, `eyeball_equator`, `eye_upper` and
    `eye_lower` (the lid edges, running with the columns, sharing the corners), `lid_loop`
    (both edges as one closed loop) and `lid_margin` (the ring tucked into the eyeball);
    `lip_ring_upper` / `lip_ring_lower` (the lip edges from the subject's left corner to
    the right one, sharing the corners), `mouth_loop`, `mouth_cavity_rings` (rings x loop)
    and `mouth_cavity_centre`.
    """

    def __init__(self):
        self.theta = _azimuths()
        self.phi, self.j_eye, self.j_mouth = _row_elevations()
        self.n_grid = N_ROWS * N_COLS + 2
        self.bottom, self.top = N_ROWS * N_COLS, N_ROWS * N_COLS + 1
        self.lens_centres = self._lens_centres()
        self.slits = self._slits()  # name -> (row, columns incl. corners, duplicate indices)
        self.n_verts = self.n_grid + sum(len(s[2]) for s in self.slits.values())
        self.groups: dict[str, np.ndarray] = {}
        self.faces, self.uv_faces, self.islands = [], [], []
        self.uv = [self._grid_uv()]
        self._grid_faces()
        for side in ("left", "right"):
            self._lid_margin(side)
        self._mouth_cavity()
        for side, u in (("left", 0.075), ("right", 0.225)):
            self._eyeball(side, u)

    # -- parameters ---------------------------------------------------------------------
    def grid_index(self, i, j):
        return (np.asarray(j) - 1) * N_COLS + np.asarray(i) % N_COLS

    def _lens_centres(self) -> dict:
        eye = _eye_slit_point()
        ear = (_azimuth(EAR_CENTRE), _elevation(EAR_CENTRE))
        return {
            "ear_left": ear,
            "ear_right": (-ear[0], ear[1]),
            "mouth": (0.0, self.phi[self.j_mouth - 1]),
            "eye_left": (_azimuth(eye), self.phi[self.j_eye - 1]),
            "eye_right": (-_azimuth(eye), self.phi[self.j_eye - 1]),
        }

    def lensed(self, theta, phi):
        for name, half, strength in LENSES:
            theta, phi = _lens(theta, phi, self.lens_centres[name], half, strength)
        return theta, phi

    def _slit_columns(self, row, theta_lo, theta_hi):
        """Columns whose lensed azimuth on `row` is nearest the two corner azimuths."""
        th, _ = self.lensed(self.theta, np.full(N_COLS, self.phi[row - 1]))
        first, last = np.abs(th - theta_lo).argmin(), np.abs(th - theta_hi).argmin()
        return np.arange(first, last + 1)

    def _slits(self) -> dict:
        eye = _eye_slit_point()
        inner = _azimuth(eye - [EYE_HALF_WIDTH[0], 0, 0.003])
        outer = _azimuth(eye + [EYE_HALF_WIDTH[1], 0, -0.006])
        mouth = _azimuth([MOUTH_HALF_WIDTH, MOUTH_Y, MOUTH_Z - 0.009])
        spans = {
            "eye_left": (self.j_eye, inner, outer),
            "eye_right": (self.j_eye, -outer, -inner),
            "mouth": (self.j_mouth, -mouth, mouth),
        }
        out, next_index = {}, self.n_grid
        for name, (row, lo, hi) in spans.items():
            cols = self._slit_columns(row, lo, hi)
            dup = np.arange(next_index, next_index + len(cols) - 2)
            out[name] = (row, cols, dup)
            next_index += len(dup)
        return out

    def below(self, i, j):
        """Index of grid vertex (i, j) as seen from the faces below it (slits doubled)."""
        idx = self.grid_index(i, j)
        for row, cols, dup in self.slits.values():
            for col, d in zip(cols[1:-1], dup, strict=True):
                idx = np.where((np.asarray(j) == row) & (np.asarray(i) % N_COLS == col), d, idx)
        return idx

    # -- skin grid ----------------------------------------------------------------------
    def _grid_uv(self) -> np.ndarray:
        """Grid UVs: (N_COLS+1) columns per row (the seam doubled), then one per pole column."""
        u = np.arange(N_COLS + 1) / N_COLS
        v = SKIN_V0 + (1 - SKIN_V0) * np.arange(1, N_ROWS + 1) / (N_ROWS + 1)
        uu, vv = np.meshgrid(u, v)
        mid = (np.arange(N_COLS) + 0.5) / N_COLS
        poles = [np.stack([mid, np.full(N_COLS, v0)], 1) for v0 in (SKIN_V0, 1.0)]
        return np.concatenate([np.stack([uu, vv], -1).reshape(-1, 2), *poles])

    def _grid_uv_index(self, i, j):
        return (np.asarray(j) - 1) * (N_COLS + 1) + np.asarray(i)

    def _grid_faces(self):
        i, j = np.meshgrid(np.arange(N_COLS), np.arange(1, N_ROWS), indexing="xy")
        i, j = i.ravel(), j.ravel()
        a, b = self.grid_index(i, j), self.grid_index(i + 1, j)
        c, d = self.below(i + 1, j + 1), self.below(i, j + 1)
        ta, tb = self._grid_uv_index(i, j), self._grid_uv_index(i + 1, j)
        tc, td = self._grid_uv_index(i + 1, j + 1), self._grid_uv_index(i, j + 1)
        # mirror-symmetric diagonals: a-c on the subject's left half, b-d on the right
        left = (i >= N_COLS // 2)[:, None]
        quads = np.where(left, np.stack([a, b, c, a, c, d], 1), np.stack([a, b, d, b, c, d], 1))
        uvq = np.where(
            left, np.stack([ta, tb, tc, ta, tc, td], 1), np.stack([ta, tb, td, tb, tc, td], 1)
        )
        cols = np.arange(N_COLS)
        n_uv_grid = N_ROWS * (N_COLS + 1)
        fans = [
            np.stack(
                [
                    np.full(N_COLS, self.bottom),
                    self.grid_index(cols + 1, 1),
                    self.grid_index(cols, 1),
                ],
                1,
            ),
            np.stack(
                [
                    self.grid_index(cols, N_ROWS),
                    self.grid_index(cols + 1, N_ROWS),
                    np.full(N_COLS, self.top),
                ],
                1,
            ),
        ]
        t = self._grid_uv_index
        fan_uv = [
            np.stack([n_uv_grid + cols, t(cols + 1, 1), t(cols, 1)], 1),
            np.stack([t(cols, N_ROWS), t(cols + 1, N_ROWS), n_uv_grid + N_COLS + cols], 1),
        ]
        self._add(
            np.concatenate([quads.reshape(-1, 3), *fans]),
            np.concatenate([uvq.reshape(-1, 3), *fan_uv]),
            "skin",
            uv_offset=0,
        )

    def _add(self, faces, uv_faces, island, uv_offset=None, uv=None):
        if uv is not None:
            uv_offset = sum(len(x) for x in self.uv)
            self.uv.append(uv)
        self.faces.append(np.asarray(faces))
        self.uv_faces.append(np.asarray(uv_faces) + uv_offset)
        self.islands.append(np.full(len(faces), ISLANDS.index(island)))

    def _new_vertices(self, n) -> np.ndarray:
        idx = np.arange(self.n_verts, self.n_verts + n)
        self.n_verts += n
        return idx

    def slit_loop(self, name) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(upper edge, lower edge, closed loop) of a slit; edges run with the columns and
        share the corners; the loop runs along the upper edge and back along the lower."""
        row, cols, dup = self.slits[name]
        upper = self.grid_index(cols, row)
        lower = np.concatenate([[upper[0]], dup, [upper[-1]]])
        return upper, lower, np.concatenate([upper, lower[-2:0:-1]])

    def _strip(self, rows, island, uv_box, close_with=None):
        """Faces joining consecutive index loops (each closed), optionally a fan to a vertex.

        Rows run from the slit edge inward; each quad is wound so that the strip continues
        the skin across the shared edge. UVs: a grid in `uv_box`, the loop seam doubled.
        """
        rows = np.asarray(rows)
        n_rows, n = rows.shape
        u0, v0, u1, v1 = uv_box
        uu, vv = np.meshgrid(np.linspace(u0, u1, n + 1), np.linspace(v1, v0, n_rows + 1))
        uv = np.stack([uu, vv], -1).reshape(-1, 2)
        k = np.arange(n)
        faces, uvf = [], []
        for r in range(n_rows - 1):
            a, b = rows[r, k], rows[r, (k + 1) % n]
            ma, mb = rows[r + 1, k], rows[r + 1, (k + 1) % n]
            ta, tb = r * (n + 1) + k, r * (n + 1) + k + 1
            tma, tmb = ta + n + 1, tb + n + 1
            faces += [np.stack([b, a, ma], 1), np.stack([b, ma, mb], 1)]
            uvf += [np.stack([tb, ta, tma], 1), np.stack([tb, tma, tmb], 1)]
        if close_with is not None:
            r = n_rows - 1
            a, b = rows[r, k], rows[r, (k + 1) % n]
            ta, tb = r * (n + 1) + k, r * (n + 1) + k + 1
            faces.append(np.stack([b, a, np.full(n, close_with)], 1))
            uv[(r + 1) * (n + 1) + k, 0] += 0.5 * (u1 - u0) / n  # the fan tip, per column
            uvf.append(np.stack([tb, ta, (r + 1) * (n + 1) + k], 1))
        else:
            uv = uv[: n_rows * (n + 1)]
        self._add(np.concatenate(faces), np.concatenate(uvf), island, uv=uv)

    def _lid_margin(self, side):
        upper, lower, loop = self.slit_loop(f"eye_{side}")
        margin = self._new_vertices(len(loop))
        self.groups.update(
            {
                f"eye_upper_{side}": upper,
                f"eye_lower_{side}": lower,
                f"lid_margin_{side}": margin,
                f"lid_loop_{side}": loop,
            }
        )
        v0 = 0.01 if side == "left" else 0.08
        self._strip([loop, margin], "lid_margin", (0.57, v0, 0.66, v0 + 0.05))

    def _mouth_cavity(self):
        upper, lower, loop = self.slit_loop("mouth")
        rings = [self._new_vertices(len(loop)) for _ in CAVITY_RINGS]
        centre = self._new_vertices(1)[0]
        self._strip([loop, *rings], "mouth_cavity", (0.31, 0.01, 0.56, 0.14), close_with=centre)
        self.groups.update(
            {
                "lip_ring_upper": upper[::-1],
                "lip_ring_lower": lower[::-1],
                "mouth_loop": loop,
                "mouth_cavity_rings": np.stack(rings),
                "mouth_cavity_centre": np.array([centre]),
            }
        )

    def _eyeball(self, side, u_centre):
        n_r, n_s = len(EYEBALL_RINGS), EYEBALL_SEGMENTS
        idx = self._new_vertices(n_r * n_s + 2)
        rings = idx[: n_r * n_s].reshape(n_r, n_s)
        front, back = idx[-2], idx[-1]
        self.groups[f"eyeball_{side}"] = idx
        self.groups[f"eyeball_equator_{side}"] = rings[
            int(np.argmin(np.abs(EYEBALL_RINGS - np.pi / 2)))
        ]
        # UV: a disc, the cornea in the middle; radius grows with the polar angle's root so
        # the iris gets room
        radius, v_centre = 0.07, 0.075
        beta = 2 * np.pi * np.arange(n_s + 1) / n_s
        rad = radius * np.sqrt(EYEBALL_RINGS / np.pi)
        ring_uv = np.stack(
            [u_centre + rad[:, None] * np.cos(beta), v_centre + rad[:, None] * np.sin(beta)], -1
        ).reshape(-1, 2)
        mid = beta[:-1] + np.pi / n_s
        back_uv = np.stack([u_centre + radius * np.cos(mid), v_centre + radius * np.sin(mid)], 1)
        uv = np.concatenate([ring_uv, [[u_centre, v_centre]], back_uv])
        k = np.arange(n_s)
        t = lambda r, s: r * (n_s + 1) + s  # noqa: E731
        n_ring_uv = n_r * (n_s + 1)
        # wound so the normals point out of the sphere
        faces = [np.stack([np.full(n_s, front), rings[0, k], rings[0, (k + 1) % n_s]], 1)]
        uvf = [np.stack([np.full(n_s, n_ring_uv), t(0, k), t(0, k + 1)], 1)]
        for r in range(n_r - 1):
            a, b = rings[r, k], rings[r, (k + 1) % n_s]
            c, d = rings[r + 1, (k + 1) % n_s], rings[r + 1, k]
            faces += [np.stack([a, c, b], 1), np.stack([a, d, c], 1)]
            uvf += [
                np.stack([t(r, k), t(r + 1, k + 1), t(r, k + 1)], 1),
                np.stack([t(r, k), t(r + 1, k), t(r + 1, k + 1)], 1),
            ]
        last = n_r - 1
        faces.append(np.stack([rings[last, k], np.full(n_s, back), rings[last, (k + 1) % n_s]], 1))
        uvf.append(np.stack([t(last, k), n_ring_uv + 1 + k, t(last, k + 1)], 1))
        self._add(np.concatenate(faces), np.concatenate(uvf), "eyeball", uv=uv)


def _eyelid_opening(topo: _Topology, theta, phi, side_up, blink):
    """Shift elevations so each eye slit opens into an almond (or closes, blink = 1)."""
    phi = phi.copy()
    for name, b in (("eye_left", blink[0]), ("eye_right", blink[1])):
        row, cols, _ = topo.slits[name]
        th, _ = topo.lensed(topo.theta[cols], np.full(len(cols), topo.phi[row - 1]))
        lo, hi = th[0], th[-1]
        t = np.clip((np.abs(theta) - min(abs(lo), abs(hi))) / abs(hi - lo), 0.0, 1.0)
        shape_up = np.sin(np.pi * t**0.85) ** 0.9  # upper lid peaks toward the nose
        shape_down = np.sin(np.pi * t**1.2) ** 0.9  # lower lid dips toward the temple
        on_side = np.sign(theta) == np.sign(lo + hi)
        shape_up, shape_down = shape_up * on_side, shape_down * on_side
        close = EYE_CLOSE_AT * EYE_OPEN_DOWN * shape_down
        up = (1 - b) * EYE_OPEN_UP * shape_up - b * close
        down = -((1 - b) * EYE_OPEN_DOWN * shape_down + b * close)
        slit = topo.phi[row - 1]
        d_up, d_down = np.maximum(phi - slit, 0), np.maximum(slit - phi, 0)
        phi += np.where(
            side_up,
            up * np.exp(-((d_up / EYE_FALLOFF_UP) ** 2)),
            down * np.exp(-((d_down / EYE_FALLOFF_DOWN) ** 2)),
        )
    return phi


def _directions(theta, phi):
    return np.stack([np.cos(phi) * np.sin(theta), np.sin(phi), np.cos(phi) * np.cos(theta)], -1)


@functools.cache
def topology() -> _Topology:
    return _Topology()


def _skin_directions(topo: _Topology, blink) -> tuple[np.ndarray, np.ndarray]:
    """(vertex indices, ray directions) of the skin grid and the slit duplicates."""
    j, i = np.meshgrid(np.arange(1, N_ROWS + 1), np.arange(N_COLS), indexing="ij")
    theta, phi = topo.theta[i.ravel()], topo.phi[j.ravel() - 1]
    idx = [topo.grid_index(i.ravel(), j.ravel())]
    for row, cols, dup in topo.slits.values():
        theta = np.concatenate([theta, topo.theta[cols[1:-1]]])
        phi = np.concatenate([phi, np.full(len(dup), topo.phi[row - 1])])
        idx.append(dup)
    idx = np.concatenate(idx)
    # above the eye slit row, plus the row itself except its duplicates (the lower lids)
    side_up = phi >= topo.phi[topo.j_eye - 1]
    side_up[N_ROWS * N_COLS :] = False
    theta, phi = topo.lensed(theta, phi)
    phi = _eyelid_opening(topo, theta, phi, side_up, blink)
    return idx, _directions(theta, phi)


def build_head() -> HeadMesh:
    """The head mesh with its neutral geometry."""
    topo = topology()
    verts = np.zeros((topo.n_verts, 3))
    idx, directions = _skin_directions(topo, (0.0, 0.0))
    verts[idx] = project_rays(directions)
    verts[[topo.bottom, topo.top]] = project_rays(np.array([[0.0, -1, 0], [0, 1, 0]]))
    _place_lid_margins(topo, verts)
    _place_mouth_cavity(topo, verts)
    _place_eyeballs(topo, verts)
    return HeadMesh(
        verts=verts,
        faces=np.concatenate(topo.faces),
        uv=np.concatenate(topo.uv),
        uv_faces=np.concatenate(topo.uv_faces),
        face_island=np.concatenate(topo.islands),
        groups=dict(topo.groups),
    )


def closed_lids(head: HeadMesh, blink) -> np.ndarray:
    """Vertex positions with the lids closed by `blink` (left, right; 1 = shut): the lid
    parameters slide together and only the vertices that moved are placed again."""
    topo = topology()
    idx, neutral = _skin_directions(topo, (0.0, 0.0))
    _, closed = _skin_directions(topo, blink)
    moved = (closed != neutral).any(axis=1)
    verts = head.verts.copy()
    verts[idx[moved]] = project_rays(closed[moved])
    _place_lid_margins(topo, verts)
    return verts


def eye_centres() -> np.ndarray:
    """(2,3): the left and the right eyeball centre."""
    return np.stack([EYE_CENTRE, EYE_CENTRE * [-1, 1, 1]])


def _place_lid_margins(topo, verts):
    for side, centre in zip(("left", "right"), eye_centres(), strict=True):
        edge = verts[topo.groups[f"lid_loop_{side}"]]
        out = edge - centre
        out /= np.linalg.norm(out, axis=1, keepdims=True)
        verts[topo.groups[f"lid_margin_{side}"]] = centre + (EYE_RADIUS - MARGIN_DEPTH) * out


def _place_mouth_cavity(topo, verts):
    """Rings from the lip edges back into the head, ballooning up and down, then a tip."""
    loop = verts[topo.groups["mouth_loop"]]
    n_up = len(topo.groups["lip_ring_upper"])
    sign = np.where(np.arange(len(loop)) < n_up, 1.0, -1.0)
    sign[[0, n_up - 1]] = 0.0  # corners
    x = loop[:, 0]
    across = np.sqrt(np.clip(1 - (x / (MOUTH_HALF_WIDTH * 1.05)) ** 2, 0, 1))
    for ring, (depth, height) in zip(topo.groups["mouth_cavity_rings"], CAVITY_RINGS, strict=True):
        p = loop.copy()
        p[:, 0] *= 1 - 0.25 * depth / CAVITY_RINGS[-1][0]
        p[:, 1] = MOUTH_Y + sign * CAVITY_HEIGHT * height * across
        p[:, 2] = loop[:, 2] - depth
        verts[ring] = p
    last_depth = CAVITY_RINGS[-1][0]
    verts[topo.groups["mouth_cavity_centre"]] = [0.0, MOUTH_Y, MOUTH_Z - last_depth - 0.008]


def _place_eyeballs(topo, verts):
    beta = 2 * np.pi * np.arange(EYEBALL_SEGMENTS) / EYEBALL_SEGMENTS
    alpha = EYEBALL_RINGS[:, None]
    bulge = CORNEA_BULGE * np.clip(1 - (alpha / 0.6) ** 2, 0, 1) ** 2
    for side, centre in zip(("left", "right"), eye_centres(), strict=True):
        r = EYE_RADIUS + bulge
        ring = np.stack(
            [
                r * np.sin(alpha) * np.cos(beta),
                r * np.sin(alpha) * np.sin(beta),
                r * np.cos(alpha) * np.ones_like(beta),
            ],
            -1,
        ).reshape(-1, 3)
        poles = np.array([[0, 0, EYE_RADIUS + CORNEA_BULGE], [0, 0, -EYE_RADIUS]])
        verts[topo.groups[f"eyeball_{side}"]] = centre + np.concatenate([ring, poles])
