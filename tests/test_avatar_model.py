"""The torch avatar: structure, sane initial Gaussians, head-space decoding, ablations."""

import copy
import io
import json

import numpy as np
import pytest
import torch
from test_uv_sphere_head import sphere_head

from archhead_addon.avatar.config import ABLATIONS, AvatarConfig, ablation, parameter_shapes
from archhead_addon.avatar.gaussians import SH_C0
from archhead_addon.avatar.model import ArchHeadAvatar
from archhead_addon.flame.lbs import forward as flame_forward
from archhead_addon.rotations import axis_angle_to_matrix, axis_angle_to_quaternion
from archhead_addon.splat.colour_space import srgb_to_linear
from archhead_addon.uv.raster import position_map

ATTRS = ("means", "log_scales", "quats", "opacity_logits", "sh", "offsets")


def make_avatar(config=None, seed=0, random_weights=True, head=None):
    """An avatar on the sphere head; with random_weights every parameter is drawn at a scale
    that makes all inputs matter (the untrained init is nearly constant by design)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    avatar = ArchHeadAvatar.create(
        head or sphere_head(), identity_shape=rng.normal(size=10), config=config
    )
    if random_weights:
        with torch.no_grad():
            for p in avatar.parameters():
                fan_in = p.shape[1] if p.ndim == 2 else 1
                scale = 1.5 / np.sqrt(fan_in) if p.ndim == 2 else (1.0 if p.ndim == 3 else 0.3)
                p.normal_(0.0, scale)
    return avatar


def frame_codes(seed=1, scale=1.0):
    rng = np.random.default_rng(seed)
    return {
        "expr": scale * rng.normal(size=100),
        "jaw": scale * rng.normal(size=3) * 0.3,
        "neck": scale * rng.normal(size=3) * 0.2,
        "eyes": scale * rng.normal(size=6) * 0.2,
        "rotation": rng.normal(size=3) * 0.5,
        "translation": rng.normal(size=3) * 0.2,
    }


@pytest.mark.parametrize("name", sorted(ABLATIONS))
def test_parameters_match_the_checkpoint_layout_for_every_ablation(name):
    config = ablation(name, n_expr=100)
    avatar = ArchHeadAvatar(sphere_head(), np.zeros(10), config, "sphere")
    shapes = {k: tuple(v.shape) for k, v in avatar.state_dict().items() if k != "identity_shape"}
    assert shapes == parameter_shapes(config)
    assert config.in_dim == (160 if config.levels else 96)
    assert AvatarConfig.from_json(config.to_json()) == config


def test_untrained_avatar_starts_as_a_sane_surface():
    avatar = make_avatar(random_weights=False)
    for lod in (0.0, 1.0):
        with torch.no_grad():
            g = avatar(lod, **frame_codes())
        size = g.resolution
        table = avatar.raster.table(size)
        texel_log = np.log(avatar.face_scale[table.face] / size)
        assert g.offsets.norm(dim=1).max() < 1e-3  # under a millimetre
        assert np.abs(g.log_scales.numpy() - texel_log[:, None]).max() < 0.1  # texel-sized
        assert torch.allclose(g.quats.norm(dim=1), torch.ones(len(g)), atol=1e-6)
        opacity = torch.sigmoid(g.opacity_logits)
        assert 0.15 < opacity.min() and opacity.max() < 0.25
        rgb = 0.5 + SH_C0 * g.sh[:, 0]  # linear: the grey start, linearised
        assert (rgb - float(srgb_to_linear(np.array(0.5)))).abs().max() < 0.05
        assert g.sh.shape == (len(g), avatar.config.sh_coeffs, 3)
        assert g.uv_texel.dtype == torch.int64


def test_sh_degree_sets_the_colour_head_and_old_checkpoints_read_as_degree_3():
    """Degree 0 (the default) gives one RGB per Gaussian; degree 3 the 16 coefficients, the
    higher bands starting near zero. A config written before the field existed is degree 3."""
    for degree in (0, 1, 3):
        config = AvatarConfig(n_expr=sphere_head().n_expr, sh_degree=degree)
        avatar = make_avatar(config, random_weights=False)
        with torch.no_grad():
            g = avatar(0.0, **frame_codes())
        assert g.sh.shape == (len(g), (degree + 1) ** 2, 3)
        assert degree == 0 or g.sh[:, 1:].abs().max() < 0.05
    assert AvatarConfig().sh_degree == 0
    old = json.loads(AvatarConfig().to_json())
    del old["sh_degree"]
    assert AvatarConfig.from_json(json.dumps(old)).sh_degree == 3
    with pytest.raises(ValueError, match="sh_degree"):
        AvatarConfig(sh_degree=4)


def test_global_rotation_and_translation_move_the_head_rigidly():
    """Decoding is in head space; the global transform then matches FLAME's own."""
    avatar = make_avatar()
    codes = frame_codes()
    rot, trans = codes.pop("rotation"), codes.pop("translation")
    with torch.no_grad():
        still = avatar(1.0, **codes)
        moved = avatar(1.0, rotation=rot, translation=trans, **codes)
    posed = flame_forward(
        avatar.mesh,
        shape=avatar.identity_shape.numpy().astype(float),
        rotation=rot,
        translation=trans,
        **codes,
    )[0]
    table = avatar.raster.table(moved.resolution)
    surface = position_map(posed, avatar.mesh.faces[table.face], table.bary)
    r = axis_angle_to_matrix(rot)
    np.testing.assert_allclose(
        moved.means.numpy(), surface + still.offsets.numpy() @ r.T, atol=2e-6
    )
    w, x, y, z = axis_angle_to_quaternion(rot)
    left = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])
    np.testing.assert_allclose(moved.quats.numpy(), still.quats.numpy() @ left.T, atol=1e-6)
    for name in ("log_scales", "opacity_logits", "sh", "offsets"):
        torch.testing.assert_close(getattr(moved, name), getattr(still, name))


@pytest.mark.parametrize("name", ["full", "no_fmap", "fmap128"])
def test_gradients_reach_every_parameter(name):
    avatar = make_avatar(ablation(name, n_expr=100))
    g = avatar(0.9, **frame_codes())  # every level keeps a positive blend weight at any S
    loss = sum(getattr(g, a).float().square().mean() for a in ATTRS)
    loss.backward()
    for pname, p in avatar.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, pname
    assert all(torch.isfinite(p.grad).all() for p in avatar.parameters())


def test_codes_of_the_wrong_width_are_refused():
    avatar = make_avatar(random_weights=False)
    with pytest.raises(ValueError, match="jaw"):
        avatar(0.5, jaw=np.zeros(4))
    with pytest.raises(ValueError, match="expr"):
        avatar(0.5, expr=np.zeros(101))
    with pytest.raises(ValueError, match="'neck' contains NaN"):
        avatar(0.5, neck=[0.0, np.nan, 0.0])
    with torch.no_grad():
        short = avatar(0.5, expr=np.ones(20))
        padded = avatar(0.5, expr=np.r_[np.ones(20), np.zeros(80)])
    torch.testing.assert_close(short.means, padded.means)


def test_the_module_pickles_and_deep_copies_with_its_caches():
    avatar = make_avatar()
    codes = frame_codes(seed=3)
    with torch.no_grad():
        before = avatar(0.8, **codes)
        buffer = io.BytesIO()
        torch.save(avatar, buffer)  # the per-resolution caches pickle without their tables
        twin = copy.deepcopy(avatar)
        torch.testing.assert_close(twin(0.8, **codes).sh, before.sh, atol=0, rtol=0)
        assert twin.level_cache.misses == 1 and len(avatar.level_cache) == 1


def test_every_resolution_a_run_samples_stays_cached():
    """Stage 2 draws S anywhere in [s_min, s_max]: once each has been built, no step builds a
    table again (a cache bounded by count rebuilt most of them, a UV raster each time)."""
    avatar = make_avatar(AvatarConfig(s_max=48, s_min=8, levels=(48, 16), n_expr=100))
    cfg, cache = avatar.config, avatar.level_cache
    sizes = range(cfg.s_min, cfg.s_max + 1)
    with torch.no_grad():
        for _ in range(2):
            for lod in np.linspace(0.0, 1.0, 4 * len(sizes)):
                avatar(float(lod), **frame_codes(seed=3))
    assert cache.misses == len(sizes) == len(cache)
    assert cache.hits == 8 * len(sizes) - cache.misses


def test_flame_carries_the_identity_and_follows_a_loaded_one():
    """The avatar's FLAME has the identity in its template (no identity product per frame),
    the same vertices as FLAME given the identity code; a state dict with another identity
    bakes that one in."""
    avatar = make_avatar()
    head = avatar.mesh
    codes = {"expr": np.linspace(-1, 1, head.n_expr), "jaw": [0.2, 0.0, 0.0]}
    with torch.no_grad():
        baked = avatar.flame(**codes)[0].numpy()
    full = flame_forward(head, shape=avatar.identity_shape.numpy(), **codes)[0]
    np.testing.assert_allclose(baked, full, atol=1e-6)

    other = make_avatar(seed=5)
    assert not torch.equal(other.identity_shape, avatar.identity_shape)
    avatar.load_state_dict(other.state_dict())
    with torch.no_grad():
        torch.testing.assert_close(avatar.flame(**codes), other.flame(**codes))
