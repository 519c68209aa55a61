"""The built-in head model: determinism, cache, structure, rig, bases, UVs, albedo, a render."""

import hashlib
import importlib.util
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import archhead_addon.flame.builtin as builtin
from archhead_addon.flame.builtin import EXPRESSION_NAMES, IDENTITY_NAMES, MODEL_ID
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.model import PART_EYE, PART_MOUTH
from archhead_addon.uv.free_space import free_uv_box
from archhead_addon.uv.raster import rasterize

RENDER_SCRIPT = Path(__file__).parent / "blender" / "render_builtin_model.py"


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("archhead_cache")


@pytest.fixture(scope="module")
def model(cache_dir):
    return builtin.builtin_model(cache_dir=cache_dir)


def _digest(arrays):
    h = hashlib.sha256()
    for key in sorted(arrays):
        a = np.ascontiguousarray(arrays[key])
        h.update(key.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


def test_generation_is_deterministic_and_cached(model, cache_dir):
    path = builtin.cache_path(cache_dir)
    with np.load(path) as z:
        cached = {k: z[k] for k in z.files}
    assert _digest(builtin.generate_arrays()) == _digest(cached)
    assert builtin.builtin_model(cache_dir=cache_dir) is model  # in memory
    builtin._MEMORY.clear()
    start = time.perf_counter()
    again = builtin.builtin_model(cache_dir=cache_dir)  # from disk
    assert time.perf_counter() - start < 2.0
    assert _digest(again.to_arrays()) == _digest(model.to_arrays())


def test_structure(model):
    assert 4000 <= model.n_verts <= 6000
    assert model.model_id == MODEL_ID and model.source == "builtin"
    assert (model.n_shape, model.n_expr) == (300, 100)
    assert model.parents.tolist() == [-1, 0, 1, 1, 1]
    # one consistent winding: no directed edge twice; the only open edges are the lid
    # margins' inner rims, tucked inside the eyeballs
    f = model.faces
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert max(Counter(map(tuple, directed)).values()) == 1
    undirected = Counter(map(tuple, np.sort(directed, axis=1)))
    open_edges = [e for e, n in undirected.items() if n == 1]
    eyes = model.v_template[np.array(open_edges).ravel()]
    centres = model.j_regressor[3:] @ model.v_template
    dist = np.linalg.norm(eyes[:, None] - centres[None], axis=2).min(1)
    assert (dist < 0.0125).all()
    assert max(undirected.values()) == 2
    v = model.v_template
    area = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    assert area.min() > 1e-10


def test_skinning_and_joints(model):
    w, reg, v = model.weights, model.j_regressor, model.v_template
    assert np.allclose(w.sum(1), 1, atol=1e-6) and w.min() >= 0
    assert np.allclose(reg.sum(1), 1, atol=1e-6) and reg.min() >= 0
    joints = reg @ v
    eye_verts = [np.flatnonzero(w[:, j] > 0.999) for j in (3, 4)]
    for j, idx in zip((3, 4), eye_verts, strict=True):
        assert len(idx) > 100 and (w[idx, j] == 1).all()
        assert np.allclose(joints[j], (v[idx].min(0) + v[idx].max(0)) / 2, atol=1e-3)
    assert joints[3, 0] > 0.02 and joints[4, 0] < -0.02  # left eye on +x
    assert np.allclose(joints[:3, 0], 0, atol=1e-4)
    assert joints[0, 1] < joints[1, 1] < joints[2, 1] < joints[3, 1]  # root, neck, jaw, eyes
    # the chin follows the jaw, the crown and the upper lip do not
    chin = np.argmin(np.linalg.norm(v - [0.0, -0.09, 0.095], axis=1))
    assert w[chin, 2] > 0.9
    assert w[np.argmax(v[:, 1]), 1] == 1
    assert (w[model.lip_ring_upper[1:-1], 2] == 0).all()
    assert (w[model.lip_ring_lower[1:-1], 2] == 1).all()


def test_lip_rings(model):
    up, low = model.lip_ring_upper, model.lip_ring_lower
    v = model.v_template
    assert len(up) == len(low) >= 9
    assert up[0] == low[0] and up[-1] == low[-1]  # shared corners
    assert v[up[0], 0] > 0.02 and v[up[-1], 0] < -0.02  # subject's left corner first
    assert (np.diff(v[up, 0]) < 0).all() and (np.diff(v[low, 0]) < 0).all()
    assert np.allclose(v[up], v[low], atol=1e-6)  # the mouth is closed at rest
    edges = set(
        map(
            tuple,
            np.sort(
                np.concatenate(
                    [model.faces[:, [0, 1]], model.faces[:, [1, 2]], model.faces[:, [2, 0]]]
                ),
                axis=1,
            ),
        )
    )
    for ring in (up, low):
        assert all(tuple(sorted(e)) in edges for e in zip(ring[:-1], ring[1:], strict=True))
    assert (model.vertex_parts[up] == PART_MOUTH).all()
    assert (model.vertex_parts[model.weights[:, 3] == 1] == PART_EYE).all()


def _strictly_inside_texels(uv, uv_faces, size):
    """Flat indices of texel centres strictly inside each UV triangle, all faces together
    (a texel listed twice lies inside two triangles)."""
    tri = uv[uv_faces] * size - 0.5  # texel-centre units
    lo, hi = np.floor(tri.min(1)).astype(int) + 1, np.floor(tri.max(1)).astype(int)
    out = []
    for t, (c0, r0), (c1, r1) in zip(tri, lo, hi, strict=True):
        cols, rows = np.meshgrid(np.arange(c0, c1 + 1), np.arange(r0, r1 + 1))
        p = np.stack([cols.ravel(), rows.ravel()], 1).astype(float)
        e = np.roll(t, -1, axis=0) - t  # the three edges
        side = e[:, 0] * (p[:, None, 1] - t[:, 1]) - e[:, 1] * (p[:, None, 0] - t[:, 0])
        inside = (side > 1e-9).all(1) | (side < -1e-9).all(1)
        out.append(rows.ravel()[inside] * size + cols.ravel()[inside])
    return np.concatenate(out)


def test_uv_layout(model):
    uv, ft = model.uv, model.uv_faces
    assert uv.min() >= 0 and uv.max() <= 1
    texels = _strictly_inside_texels(uv, ft, 256)
    assert len(np.unique(texels)) == len(texels), "UV triangles overlap"
    assert rasterize(uv, ft, 512).count / 512**2 > 0.8  # coverage
    u0, v0, u1, v1 = free_uv_box(uv, ft)  # room left for teeth
    assert (u1 - u0) * (v1 - v0) > 0.02


def test_bases_decay_and_eyeballs(model):
    ident = model.shapedirs[:, :, : model.n_shape]
    expr = model.shapedirs[:, :, model.n_shape :]
    for basis in (ident, expr):
        rms = np.sqrt((basis**2).sum(1).mean(0))
        blocks = [rms[:10].mean(), rms[10:50].mean(), rms[50:].mean()]
        assert blocks[0] > blocks[1] > blocks[2] > 0
    peak = np.abs(ident).max(axis=(0, 1))
    assert 0.002 < peak[0] < 0.005 and peak.max() < 0.005  # +-3 sigma: at most ~1.5 cm
    eyes = model.weights[:, 3] == 1
    assert np.allclose(ident[eyes], ident[eyes][:1], atol=1e-9)  # eyeballs move rigidly
    assert (expr[eyes] == 0).all() and (model.posedirs[eyes] == 0).all()
    assert len(IDENTITY_NAMES) >= 10 and len(EXPRESSION_NAMES) == 10


def test_jaw_parts_lips_and_eyes_turn(model):
    up, low = model.lip_ring_upper[1:-1], model.lip_ring_lower[1:-1]
    rest = forward(model)[0]
    opened = forward(model, jaw=np.array([0.3, 0, 0]))[0]
    assert np.linalg.norm(rest[up] - rest[low], axis=1).max() < 1e-6
    gap = np.linalg.norm(opened[up] - opened[low], axis=1)
    assert gap.mean() > 0.01 and gap.min() > 0.002
    shaped = forward(model, expr=np.eye(100)[EXPRESSION_NAMES.index("jaw_open")])[0]
    assert np.linalg.norm(shaped[up] - shaped[low], axis=1).mean() > 0.005
    turned = forward(model, eyes=np.array([0, 0.4, 0, 0, 0.4, 0]))[0]
    front = np.argmax(np.where(model.weights[:, 3] == 1, rest[:, 2], -1))
    assert turned[front, 0] - rest[front, 0] > 0.004  # the pupil moves toward +x


def _lid_gap(v, upper, lower):
    """From the lowest upper-lid vertex down to the highest lower-lid vertex."""
    return v[upper, 1].min() - v[lower, 1].max()


def test_blink_closes_the_lids(model):
    v0, w = model.v_template, model.weights
    for name, joint in (("blink_left", 3), ("blink_right", 4)):
        centre = model.j_regressor[joint] @ v0
        pupil = v0[np.argmax(np.where(w[:, joint] == 1, v0[:, 2], -1))]
        dist = np.linalg.norm(v0 - centre, axis=1)
        # lid skin in a vertical strip through the pupil (the margins inside the eyeball
        # and the eyeball itself excluded)
        lids = (
            (model.vertex_parts == PART_EYE)
            & (w[:, joint] == 0)
            & (dist > 0.0125)
            & (dist < 0.02)
            & (np.abs(v0[:, 0] - pupil[0]) < 0.002)
        )
        upper, lower = lids & (v0[:, 1] > pupil[1]), lids & (v0[:, 1] < pupil[1])
        code = np.eye(model.n_expr)[EXPRESSION_NAMES.index(name)]
        assert _lid_gap(v0, upper, lower) > 0.007  # open at rest
        for amount in (0.5, 1.0):
            v = forward(model, expr=amount * code)[0]
            assert np.linalg.norm(v[lids] - centre, axis=1).min() > 0.0125  # over the eyeball
        assert abs(_lid_gap(forward(model, expr=code)[0], upper, lower)) < 0.001  # shut


def test_albedo(model):
    a = model.albedo
    assert a.shape == (1024, 1024, 3) and a.dtype == np.uint8

    def colour(vertex):
        face = np.flatnonzero((model.faces == vertex).any(1))[0]
        t = model.uv[model.uv_faces[face][model.faces[face] == vertex][0]]
        return a[min(int((1 - t[1]) * 1024), 1023), min(int(t[0] * 1024), 1023)].astype(int)

    v, w = model.v_template, model.weights
    pupil = np.argmax(np.where(w[:, 3] == 1, v[:, 2], -1))
    assert colour(pupil).max() < 60
    lip = colour(model.lip_ring_lower[len(model.lip_ring_lower) // 2])
    assert lip[0] - lip[1] > 40  # red
    forehead = np.argmin(np.linalg.norm(v - [0.0, 0.06, 0.09], axis=1))
    skin = colour(forehead)
    assert skin[0] > 150 and skin[0] > skin[1] > skin[2]


def test_render_smoke(model, tmp_path):
    pytest.importorskip("bpy")
    from PIL import Image

    spec = importlib.util.spec_from_file_location("render_builtin_model", RENDER_SCRIPT)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    out = tmp_path / "tiny.png"
    script.render_pose(
        model, script.POSES["builtin_smile"], out, resolution=32, samples=1, transparent=True
    )
    alpha = np.asarray(Image.open(out))[..., 3]
    assert alpha[12:20, 12:20].min() > 200  # the head covers the middle of the frame
    assert alpha[0, 0] == 0
