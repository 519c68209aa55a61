import numpy as np
from synthetic_models import random_model

from archhead_addon.flame.lbs import forward
from archhead_addon.flame.model import PART_MOUTH
from archhead_addon.flame.teeth import add_teeth
from archhead_addon.rotations import axis_angle_to_matrix
from archhead_addon.uv.free_space import coverage_grid


def _model_with_mouth():
    """A random model whose first 2 x 9 vertices form a mouth (lip rings) and with a UV
    layout that uses only the left half of the texture."""
    model = random_model(n_verts=60)
    v = model.v_template.copy()
    x = np.linspace(-0.025, 0.025, 9)
    z = 0.09 - 20 * x**2
    v[:9] = np.stack([x, np.full(9, 0.002), z], 1)
    v[9:18] = np.stack([x, np.full(9, -0.002), z], 1)
    uv = np.random.default_rng(3).random((model.n_verts, 2)) * [0.45, 1.0]
    weights = np.zeros_like(model.weights)
    weights[:, 1] = 1
    return model.replace(
        v_template=v,
        lip_ring_upper=np.arange(9),
        lip_ring_lower=np.arange(9, 18),
        uv=uv,
        uv_faces=model.faces.copy(),
        weights=weights,
        vertex_parts=np.zeros(model.n_verts, np.uint8),
        albedo=np.zeros((64, 64, 3), np.uint8),
    )


def test_teeth_geometry_skinning_and_uvs():
    base = _model_with_mouth()
    model = add_teeth(base, columns=12)
    n_new = model.n_verts - base.n_verts
    assert n_new == 2 * 4 * 12 and model.model_id.endswith("+teeth")
    assert add_teeth(model) is model  # idempotent
    teeth = model.v_template[base.n_verts :]
    ring = base.v_template[:9]
    lip_z = np.interp(teeth[:, 0], ring[:, 0], ring[:, 2])
    assert (teeth[:, 2] < lip_z - 1e-3).all()  # every tooth vertex sits behind the lip line
    upper, lower = teeth[:48], teeth[48:]
    assert upper[:, 1].mean() > lower[:, 1].mean()
    assert (model.vertex_parts[base.n_verts :] == PART_MOUTH).all()
    # front faces point out of the mouth (+z)
    first_faces = model.faces[len(base.faces) :: 2 * 11 * 3][:2]
    for f in first_faces:
        a, b, c = model.v_template[f]
        assert np.cross(b - a, c - a)[2] > 0
    # jaw moves the lower arch rigidly about the jaw joint and leaves the upper arch alone
    jaw = np.array([0.35, 0.0, 0.0])
    posed = forward(model, jaw=jaw)[0]
    rest = forward(model)[0]
    np.testing.assert_allclose(posed[base.n_verts :][:48], rest[base.n_verts :][:48], atol=1e-15)
    j = model.j_regressor[2] @ model.v_template
    want = (rest[base.n_verts + 48 :] - j) @ axis_angle_to_matrix(jaw).T + j
    np.testing.assert_allclose(posed[base.n_verts + 48 :], want, atol=1e-12)
    # the teeth islands lie in the free right half and overlap no existing face
    new_uv = model.uv[len(base.uv) :]
    assert new_uv[:, 0].min() > 0.45 and new_uv.max() <= 1
    grid = coverage_grid(base.uv, base.uv_faces, 256, margin=0)
    cells = np.clip((new_uv * 256).astype(int), 0, 255)
    assert not grid[cells[:, 1], cells[:, 0]].any()
    assert (model.albedo != 0).any()  # the island is painted


def test_model_without_rings_unchanged():
    model = random_model()
    assert add_teeth(model) is model
