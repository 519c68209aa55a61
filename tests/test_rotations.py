import numpy as np
import pytest
import torch

from archhead_addon import rotations as rot


def _random_axis_angles(n, rng):
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate(
        [
            [0.0, 1e-12, 1e-7, 1e-4, 0.3, np.pi / 2, np.pi - 1e-9, np.pi],
            rng.uniform(0, np.pi, n - 8),
        ]
    )
    return axes * angles[:, None]


def _rodrigues_reference(aa):
    """Matrix exponential of the skew matrix, by scaled Taylor series (independent check)."""
    out = []
    for r in aa:
        k = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
        m = k / 64
        term, acc = np.eye(3), np.eye(3)
        for i in range(1, 30):
            term = term @ m / i
            acc = acc + term
        out.append(np.linalg.matrix_power(acc, 64))
    return np.array(out)


def test_axis_angle_matrix_against_series_and_orthonormal():
    rng = np.random.default_rng(0)
    aa = _random_axis_angles(64, rng)
    R = rot.axis_angle_to_matrix(aa)
    np.testing.assert_allclose(R, _rodrigues_reference(aa), atol=1e-12)
    np.testing.assert_allclose(
        R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )


def test_round_trips_stable_at_zero_and_pi():
    rng = np.random.default_rng(1)
    aa = _random_axis_angles(64, rng)
    R = rot.axis_angle_to_matrix(aa)
    back = rot.matrix_to_axis_angle(R)
    # at exactly pi, aa and -aa are the same rotation: compare matrices there, vectors elsewhere
    np.testing.assert_allclose(rot.axis_angle_to_matrix(back), R, atol=1e-9)
    inner = np.linalg.norm(aa, axis=1) < np.pi - 1e-6
    np.testing.assert_allclose(back[inner], aa[inner], atol=1e-9)
    q = rot.axis_angle_to_quaternion(aa)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(rot.quaternion_to_matrix(q), R, atol=1e-12)
    np.testing.assert_allclose(
        rot.rotation_6d_to_matrix(rot.matrix_to_rotation_6d(R)), R, atol=1e-12
    )


def test_matrix_to_quaternion_half_turns():
    for axis in np.eye(3):
        R = rot.axis_angle_to_matrix(axis * np.pi)
        q = rot.matrix_to_quaternion(R)
        np.testing.assert_allclose(np.abs(q), np.concatenate([[0], axis]), atol=1e-12)


def test_six_d_uses_rows_and_orthonormalises():
    R = rot.axis_angle_to_matrix(np.array([0.3, -0.2, 0.9]))
    d6 = rot.matrix_to_rotation_6d(R)
    np.testing.assert_array_equal(d6, np.concatenate([R[0], R[1]]))
    noisy = d6 * 3 + np.array([0, 0, 0, 0.01, 0, 0])  # unnormalised, slightly skewed
    R2 = rot.rotation_6d_to_matrix(noisy)
    np.testing.assert_allclose(R2 @ R2.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R2) == pytest.approx(1)


def test_zero_quaternion_is_identity_not_nan():
    assert np.array_equal(rot.quaternion_to_matrix(np.zeros(4)), np.eye(3))
    t = rot.quaternion_to_matrix(torch.zeros(2, 4, dtype=torch.float64))
    assert torch.equal(t, torch.eye(3, dtype=torch.float64).expand(2, 3, 3))


def test_torch_matches_numpy_and_gradients_finite_at_zero():
    rng = np.random.default_rng(2)
    aa = _random_axis_angles(32, rng)
    t = torch.tensor(aa, requires_grad=True)
    R = rot.axis_angle_to_matrix(t)
    np.testing.assert_allclose(R.detach().numpy(), rot.axis_angle_to_matrix(aa), atol=1e-14)
    R.sum().backward()
    assert torch.isfinite(t.grad).all()
    back = rot.matrix_to_axis_angle(R.detach())
    np.testing.assert_allclose(
        back.numpy(), rot.matrix_to_axis_angle(R.detach().numpy()), atol=1e-12
    )
    # d/dr of R at r = 0 is the skew generator: compare with autograd
    z = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    jac = torch.autograd.functional.jacobian(rot.axis_angle_to_matrix, z)
    gen = torch.zeros(3, 3, 3, dtype=torch.float64)
    gen[2, 1, 0], gen[1, 2, 0], gen[0, 2, 1], gen[2, 0, 1], gen[1, 0, 2], gen[0, 1, 2] = (
        1,
        -1,
        1,
        -1,
        1,
        -1,
    )
    torch.testing.assert_close(jac, gen)


def test_float32_stays_float32():
    aa = np.array([[0.1, 0.2, 0.3]], dtype=np.float32)
    assert rot.axis_angle_to_matrix(aa).dtype == np.float32
    assert rot.axis_angle_to_quaternion(aa).dtype == np.float32
