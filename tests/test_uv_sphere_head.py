"""A small UV-mapped FLAME-format head (a lat-long ellipsoid) for the UV and avatar tests.

Its UV layout is one rectangle island u in [0.02, 0.62], v in [0.02, 0.98] (so the right of the
map is free for the teeth island) with an exactly known area; it has lip rings, a jaw, eyes,
100 expression components and smooth blendshapes, so every path of the avatar is exercised.
"""

import numpy as np

from archhead_addon.flame.model import FlameModel, model_from_arrays

U_RANGE, V_RANGE = (0.02, 0.62), (0.02, 0.98)
RADII = np.array([0.08, 0.11, 0.10])


def sphere_head(
    n_lat: int = 40,
    n_lon: int = 64,
    n_shape: int = 10,
    n_expr: int = 100,
    with_uv: bool = True,
    lips: bool = True,
    uv_scale: float = 1.0,
    seed: int = 0,
) -> FlameModel:
    """lips=False: no lip rings, so no teeth; uv_scale shrinks the island towards (0, 0)
    (fewer texels, for tests that decode many resolutions)."""
    rng = np.random.default_rng(seed)
    lat = np.linspace(np.radians(75), np.radians(-75), n_lat + 1)
    lon = -np.pi + 2 * np.pi * np.arange(n_lon) / n_lon  # front (+z) at lon = 0
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    v = np.stack([np.cos(la) * np.sin(lo), np.sin(la), np.cos(la) * np.cos(lo)], -1)
    v = (v * RADII).reshape(-1, 3)
    r, c = np.meshgrid(np.arange(n_lat), np.arange(n_lon), indexing="ij")
    a, b = r * n_lon + c, r * n_lon + (c + 1) % n_lon
    faces = np.concatenate(
        [
            np.stack([a, a + n_lon, b], -1).reshape(-1, 3),
            np.stack([b, a + n_lon, b + n_lon], -1).reshape(-1, 3),
        ]
    )
    at, bt = r * (n_lon + 1) + c, r * (n_lon + 1) + c + 1  # UV grid has a seam column
    ft = np.concatenate(
        [
            np.stack([at, at + n_lon + 1, bt], -1).reshape(-1, 3),
            np.stack([bt, at + n_lon + 1, bt + n_lon + 1], -1).reshape(-1, 3),
        ]
    )
    uu, vv = np.meshgrid(
        np.linspace(*U_RANGE, n_lon + 1), np.linspace(V_RANGE[1], V_RANGE[0], n_lat + 1)
    )
    vt = uv_scale * np.stack([uu, vv], -1).reshape(-1, 2)

    mouth_row = n_lat // 2 + 4
    front = np.arange(n_lon // 2 - 5, n_lon // 2 + 6)  # +-5 columns around lon = 0
    eye_at = [np.array([s * 0.03, 0.03, 0.0]) for s in (1, -1)]
    eye_at = [
        e + [0, 0, RADII[2] * np.sqrt(1 - (e[0] / RADII[0]) ** 2 - (e[1] / RADII[1]) ** 2)]
        for e in eye_at
    ]
    jreg = np.zeros((5, len(v)))
    jreg[0] = 1
    jreg[1, n_lat * n_lon :] = 1  # neck: the bottom ring
    jreg[2, mouth_row * n_lon : (mouth_row + 1) * n_lon] = 1  # jaw: the mouth ring's centre
    for j, e in ((3, eye_at[0]), (4, eye_at[1])):
        jreg[j, np.argsort(np.linalg.norm(v - e, axis=1))[:4]] = 1
    jreg /= jreg.sum(1, keepdims=True)

    def sigmoid(t):
        return 1 / (1 + np.exp(-t))

    w = np.zeros((len(v), 5))
    w[:, 1] = sigmoid((-0.07 - v[:, 1]) / 0.01)
    w[:, 2] = sigmoid((v[mouth_row * n_lon, 1] - v[:, 1]) / 0.008) * sigmoid(v[:, 2] / 0.02)
    w[:, 3] = np.exp(-np.sum((v - eye_at[0]) ** 2, 1) / 0.012**2)
    w[:, 4] = np.exp(-np.sum((v - eye_at[1]) ** 2, 1) / 0.012**2)
    w[:, 0] = np.clip(1 - w[:, 1:].sum(1), 0.05, None)
    w /= w.sum(1, keepdims=True)

    n_dirs = n_shape + n_expr
    freq = rng.normal(scale=20.0, size=(n_dirs, 3))
    phase = rng.uniform(0, 2 * np.pi, n_dirs)
    direction = rng.normal(size=(n_dirs, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    amp = np.where(np.arange(n_dirs) < n_shape, 0.002, 0.0005)
    field = np.sin(v @ freq.T + phase)  # (V, n_dirs)
    shapedirs = amp * field[:, None, :] * direction.T[None]
    arrays = {
        "v_template": v,
        "f": faces,
        "shapedirs": shapedirs,
        "posedirs": 1e-4 * rng.normal(size=(len(v), 3, 36)),
        "J_regressor": jreg,
        "weights": w,
        "kintree_table": np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]]),
        "n_shape": np.int64(n_shape),
        "model_id": np.str_(f"sphere-head-{n_lat}x{n_lon}"),
    }
    if lips:
        arrays.update(
            lip_ring_upper=mouth_row * n_lon + front, lip_ring_lower=(mouth_row + 1) * n_lon + front
        )
    if with_uv:
        arrays.update(vt=vt, ft=ft)
    return model_from_arrays(arrays, source="sphere-head")


def uv_area() -> float:
    return (U_RANGE[1] - U_RANGE[0]) * (V_RANGE[1] - V_RANGE[0])


def test_sphere_head_is_a_valid_closed_band_with_one_uv_island():
    model = sphere_head()
    assert model.uv.shape == (41 * 65, 2) and model.uv_faces.shape == model.faces.shape
    tri = model.uv[model.uv_faces]
    areas = 0.5 * np.abs(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    assert np.isclose(areas.sum(), uv_area())
    # every mesh edge is shared by at most two faces and the joints lie inside the head
    edges = np.sort(model.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    assert np.unique(edges, axis=0, return_counts=True)[1].max() == 2
    joints = model.j_regressor @ model.v_template
    assert (np.abs(joints) <= RADII).all()
