import numpy as np
import pytest
import torch
from synthetic_models import random_codes, random_model

from archhead_addon.flame.lbs import forward, forward_full
from archhead_addon.flame.lbs_torch import FlameLayer
from archhead_addon.rotations import axis_angle_to_matrix


def _rel_err(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("scale", [1.0, 3.0, 10.0])
def test_numpy_and_torch_agree(scale):
    model = random_model()
    codes = random_codes(model, batch=7, scale=scale)
    ref = forward(model, **codes)
    layer = FlameLayer(model, dtype=torch.float64)
    out = layer(**{k: torch.from_numpy(v) for k, v in codes.items()}).numpy()
    assert _rel_err(out, ref) <= 1e-6
    f32 = forward_full(model, dtype=np.float32, **codes).vertices
    assert f32.dtype == np.float32
    assert _rel_err(f32.astype(np.float64), ref) <= 1e-5


def test_extreme_rotations_at_pi():
    model = random_model()
    codes = {k: np.zeros_like(v) for k, v in random_codes(model, batch=3).items()}
    for i, axis in enumerate(np.eye(3)):
        for key in ("jaw", "neck", "rotation"):
            codes[key][i] = axis * np.pi
        codes["eyes"][i] = np.concatenate([axis, -axis]) * np.pi
    ref = forward(model, **codes)
    out = FlameLayer(model, dtype=torch.float64)(**codes).numpy()
    assert np.isfinite(ref).all()
    assert _rel_err(out, ref) <= 1e-6


def test_identity_codes_give_template_and_joint_rotation_is_rigid():
    model = random_model()
    np.testing.assert_allclose(forward(model)[0], model.v_template, atol=1e-15)
    # a vertex fully skinned to the root moves rigidly about joint 0, then translates
    model = model.replace(
        weights=np.tile([1.0, 0, 0, 0, 0], (model.n_verts, 1)),
        posedirs=np.zeros_like(model.posedirs),
    )
    r, t = np.array([0.2, -0.5, 0.1]), np.array([0.01, 0.02, -0.3])
    j0 = model.j_regressor[0] @ model.v_template
    want = (model.v_template - j0) @ axis_angle_to_matrix(r).T + j0 + t
    np.testing.assert_allclose(forward(model, rotation=r, translation=t)[0], want, atol=1e-14)


def test_pose_correctives_follow_flame_feature_order():
    model = random_model()
    model = model.replace(weights=np.tile([0, 1.0, 0, 0, 0], (model.n_verts, 1)))
    jaw = np.array([0.4, 0.0, 0.0])
    feature = np.zeros(36)
    feature[9:18] = (axis_angle_to_matrix(jaw) - np.eye(3)).ravel()  # jaw is the 2nd posed joint
    expected = model.v_template + np.einsum("vcp,p->vc", model.posedirs, feature)
    np.testing.assert_allclose(forward(model, jaw=jaw)[0], expected, atol=1e-14)


def test_torch_gradients_flow_to_every_code():
    model = random_model()
    codes = {
        k: torch.tensor(v, requires_grad=True) for k, v in random_codes(model, batch=2).items()
    }
    FlameLayer(model, dtype=torch.float64)(**codes).square().sum().backward()
    for key, value in codes.items():
        assert value.grad is not None and torch.isfinite(value.grad).all(), key
        assert value.grad.abs().sum() > 0, key


def test_code_width_errors_are_explicit():
    model = random_model()
    with pytest.raises(ValueError, match="'expr'.*at most 6"):
        forward(model, expr=np.zeros((1, 7)))
    with pytest.raises(ValueError, match="'jaw'.*exactly 3"):
        forward(model, jaw=np.zeros((1, 6)))
    with pytest.raises(ValueError, match="unknown FLAME codes"):
        forward(model, pose=np.zeros(3))
    fewer = forward(model, expr=np.ones((1, 2)))
    padded = forward(model, expr=np.concatenate([np.ones((1, 2)), np.zeros((1, 4))], axis=1))
    np.testing.assert_allclose(fewer, padded, atol=1e-15)


def test_static_offset_is_added_to_the_template_and_never_sets_the_batch():
    """One frame's codes with a (V,3) offset pose one frame, not V copies of it."""
    model = random_model()
    codes = {k: v[0] for k, v in random_codes(model, batch=1).items()}
    offset = np.random.default_rng(1).normal(scale=0.002, size=(model.n_verts, 3))
    moved = forward(model, static_offset=offset, **codes)
    assert moved.shape == (1, model.n_verts, 3)
    torch_moved = FlameLayer(model, dtype=torch.float64)(static_offset=offset, **codes)
    assert torch_moved.shape == (1, model.n_verts, 3)
    assert _rel_err(torch_moved.numpy(), moved) <= 1e-6
    # without any pose the offset is carried through unchanged
    rest = forward(model, shape=codes["shape"])
    np.testing.assert_allclose(
        forward(model, shape=codes["shape"], static_offset=offset) - rest, offset[None], atol=1e-12
    )
