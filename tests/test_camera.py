"""`affine_inverse`: the inverse that the per-frame camera code uses instead of LAPACK's."""

import numpy as np
import pytest

from archhead_addon.camera import affine_inverse
from archhead_addon.rotations import axis_angle_to_matrix


def test_affine_inverse_matches_lapacks():
    rng = np.random.default_rng(0)
    for _ in range(50):
        m = np.eye(4)
        rotation = axis_angle_to_matrix(rng.normal(size=3) * 2)
        m[:3, :3] = rotation @ np.diag(rng.uniform(0.01, 50, 3))  # scaled
        m[:3, :3] += 0.3 * np.triu(rng.normal(size=(3, 3)), 1)  # and sheared
        m[:3, 3] = rng.normal(size=3) * 10
        want = np.linalg.inv(m)
        got = affine_inverse(m)
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10 * np.abs(want).max())
        np.testing.assert_allclose(got @ m, np.eye(4), atol=1e-9)


@pytest.mark.parametrize("bad", [np.diag([1.0, 0.0, 1.0, 1.0]), np.full((4, 4), np.nan)])
def test_affine_inverse_refuses_a_singular_matrix(bad):
    with pytest.raises(np.linalg.LinAlgError, match="singular or non-finite"):
        affine_inverse(bad)
