"""Extreme codes and every LOD: finite, bounded Gaussians, continuous in l within one S."""

import numpy as np
import pytest
from test_avatar_model import make_avatar
from test_uv_sphere_head import sphere_head

from archhead_addon.avatar.checkpoint import save_avatar
from archhead_addon.avatar.config import AvatarConfig
from archhead_addon.avatar.runtime import AvatarRuntime

ATTRS = ("means", "log_scales", "quats", "opacity_logits", "sh", "offsets")


def _extreme_codes():
    """Expressions at +-10 and jaw / neck / eyes / rotation turned by up to pi."""
    rng = np.random.default_rng(0)
    out = []
    for axis in np.eye(3):
        out.append(
            {
                "expr": 10 * rng.choice([-1.0, 1.0], 100),
                "jaw": np.pi * axis,
                "neck": np.pi * axis,
                "eyes": np.tile(np.pi * axis, 2),
                "rotation": np.pi * axis,
                "translation": [0.0, 0.0, 1.0],
            }
        )
    out.append(
        {
            "expr": np.full(100, -10.0),
            "jaw": [-np.pi, 0, 0],
            "neck": [0, -np.pi, 0],
            "eyes": rng.uniform(-np.pi, np.pi, 6),
        }
    )
    return out


@pytest.fixture(scope="module")
def runtimes(tmp_path_factory):
    """Runtimes of an untrained avatar (its initial bounds are known) and of random weights.
    Small (a UV island of a quarter of the area, 8 feature channels, colour head 32 wide) so
    that 101 resolutions build and decode quickly; the bounds do not depend on the sizes."""
    folder = tmp_path_factory.mktemp("stability")
    head = sphere_head(uv_scale=0.5)
    config = AvatarConfig(n_expr=100, feature_dim=8, colour_hidden=32)
    out = {}
    for name, random in (("untrained", False), ("random", True)):
        avatar = make_avatar(config, seed=11, random_weights=random, head=head)
        save_avatar(folder / f"{name}.npz", avatar)
        out[name] = AvatarRuntime.load(folder / f"{name}.npz", flame=head)
    return out


def _check(g, config):
    for name in ATTRS:
        assert np.isfinite(getattr(g, name)).all(), name
    assert (g.log_scales >= config.log_scale_min).all()
    assert (g.log_scales <= config.log_scale_max).all()
    np.testing.assert_allclose(np.linalg.norm(g.quats, axis=1), 1, atol=1e-5)


def test_every_lod_and_extreme_codes_give_finite_bounded_gaussians(runtimes):
    rt = runtimes["random"]
    codes = _extreme_codes()
    lods = np.round(np.arange(0, 1.0001, 0.01), 2)
    largest_offset = 0.0
    for i, lod in enumerate(lods):
        g = rt.decode(lod, **codes[i % len(codes)])
        _check(g, rt.config)
        assert g.resolution == int(np.floor(256 - lod * 192 + 0.5))
        largest_offset = max(largest_offset, np.abs(g.offsets).max())
    neutral = max(np.abs(rt.decode(lod).offsets).max() for lod in (0, 0.5, 1))
    # the driving code is tanh-bounded and the PE is bounded, so extreme codes cannot blow
    # the offsets up far beyond those of a neutral face
    assert largest_offset < 3 * neutral


def test_untrained_avatar_stays_sane_under_extreme_codes(runtimes):
    rt = runtimes["untrained"]
    for lod in (0.0, 0.5, 1.0):
        for codes in _extreme_codes():
            g = rt.decode(lod, **codes)
            _check(g, rt.config)
            assert np.linalg.norm(g.offsets, axis=1).max() < 2e-3
            table = rt.raster.table(g.resolution)
            base = np.log(rt.face_scale[table.face] / g.resolution)[:, None]
            assert np.abs(g.log_scales - base).max() < 0.5
            opacity = 1 / (1 + np.exp(-g.opacity_logits))
            assert 0.05 < opacity.min() and opacity.max() < 0.5


def test_attributes_change_continuously_with_lod_while_s_is_constant(runtimes):
    rt = runtimes["random"]
    lo = 0.3  # S = round(256 - 0.3 * 192) = 198 for l in [0.2974, 0.3026)
    steps = (1e-3, 1e-4, 1e-5)
    base = rt.decode(lo)
    changes = []
    for step in steps:
        g = rt.decode(lo + step)
        assert g.resolution == base.resolution
        changes.append(max(np.abs(getattr(g, a) - getattr(base, a)).max() for a in ATTRS))
    # no jump: the change shrinks in proportion to the step (up to float32 rounding)
    assert changes[0] < 0.05
    assert changes[1] < 0.2 * changes[0] + 1e-5 and changes[2] < 0.2 * changes[1] + 1e-5


def test_non_finite_codes_are_refused(runtimes):
    rt = runtimes["random"]
    with pytest.raises(ValueError, match="'jaw' contains NaN"):
        rt.decode(0.5, jaw=[np.nan, 0, 0])
    with pytest.raises(ValueError, match="'expr' contains NaN or Inf"):
        rt.decode(0.5, expr=np.r_[np.inf, np.zeros(99)])
