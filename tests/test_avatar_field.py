"""LOD -> resolution (eq. 3), the blend weights (eq. 4-5) and the bicubic resamplers (numpy and
torch), held to F.interpolate."""

import math
import warnings

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from archhead_addon.avatar.bicubic import resize
from archhead_addon.avatar.lod import blend_weights, resolution_for_lod
from archhead_addon.avatar.resample import resample_plan, texel_features, texel_features_torch


def test_lod_to_resolution():
    assert resolution_for_lod(0.0) == (0.0, 256)
    assert resolution_for_lod(1.0) == (1.0, 64)
    assert resolution_for_lod(0.5) == (0.5, 160)
    assert resolution_for_lod(0.37)[1] == 185  # 256 - 0.37 * 192 = 184.96
    half = 0.5 / 192  # S = 255.5 exactly: rounds up
    assert resolution_for_lod(half)[1] == 256
    assert resolution_for_lod(0.25, s_max=128, s_min=32) == (0.25, 104)
    sizes = [resolution_for_lod(i / 100)[1] for i in range(101)]
    assert all(a >= b for a, b in zip(sizes, sizes[1:], strict=False))


def test_lod_outside_range_is_clamped_with_a_warning():
    with pytest.warns(UserWarning, match="outside"):
        assert resolution_for_lod(-0.2) == (0.0, 256)
    with pytest.warns(UserWarning, match="outside"):
        assert resolution_for_lod(1.5) == (1.0, 64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        resolution_for_lod(1.0)
    with pytest.raises(ValueError, match="NaN"):
        resolution_for_lod(float("nan"))


def test_blend_weights_match_a_hand_computation():
    # S = 200, levels 256, 128, 64, tau = 0.35:
    #   |ln S_i - ln S| = ln 1.28 = 0.246860, ln 1.5625 = 0.446287, ln 3.125 = 1.139434
    #   exp(-d / 0.35)  = 0.493953,           0.279401,             0.038561   (sum 0.811915)
    #   w               = 0.608380,           0.344126,             0.047493
    w = blend_weights((256, 128, 64), 200, 0.35)
    np.testing.assert_allclose(w, [0.608380, 0.344126, 0.047493], atol=2e-6)
    # at a level's own size that level gets the most, yet every weight stays positive:
    # S = 128: d = ln 2, 0, ln 2 -> w = (e, 1, e) / (1 + 2e), e = exp(-ln 2 / 0.35) = 0.138011
    e = 0.138011
    np.testing.assert_allclose(
        blend_weights((256, 128, 64), 128, 0.35),
        [e / (1 + 2 * e), 1 / (1 + 2 * e), e / (1 + 2 * e)],
        atol=2e-6,
    )
    assert blend_weights((128,), 77, 0.35).tolist() == [1.0]


def test_blend_weights_change_continuously_across_resolutions():
    sizes = np.arange(64, 256.001, 0.01)
    w = np.stack([blend_weights((256, 128, 64), s, 0.35) for s in sizes])
    # |dw/dS| <= 2 / (tau S): a step of 0.01 moves a weight by at most 0.01 * 2 / (0.35 * 64)
    assert np.abs(np.diff(w, axis=0)).max() < 0.01 * 2 / (0.35 * 64)
    whole = np.stack([blend_weights((256, 128, 64), s, 0.35) for s in range(64, 257)])
    assert np.abs(np.diff(whole, axis=0)).max() < 0.1  # neighbouring integer S
    assert (w > 0).all() and np.allclose(w.sum(1), 1)


@pytest.mark.parametrize("src", [64, 128, 256])
@pytest.mark.parametrize("dst", [64, 97, 128, 185, 255, 256])
def test_numpy_bicubic_reproduces_torch(src, dst):
    maps = np.random.default_rng(src + dst).normal(size=(8, src, src)).astype(np.float32)
    ref = F.interpolate(
        torch.from_numpy(maps)[None], size=(dst, dst), mode="bicubic", align_corners=False
    )[0].numpy()
    out = resize(maps, dst)
    assert out.dtype == np.float32 and out.shape == (8, dst, dst)
    np.testing.assert_allclose(out, ref, atol=1e-5)
    if src == dst:
        np.testing.assert_array_equal(out, maps)


def test_bicubic_kernel_is_keys_with_a_minus_three_quarters_and_clamped_borders():
    from archhead_addon.avatar.bicubic import taps

    idx, w = taps(4, 8)  # upsampling x2: source positions -0.25, 0.25, 0.75, ...
    a = -0.75

    def k(x):
        x = abs(x)
        return (a + 2) * x**3 - (a + 3) * x**2 + 1 if x <= 1 else a * (x**3 - 5 * x**2 + 8 * x - 4)

    # interior output 3 sits at source 1.25: taps at 0..3 with t = 0.25
    assert idx[3].tolist() == [0, 1, 2, 3]
    np.testing.assert_allclose(w[3], [k(1.25), k(0.25), k(0.75), k(1.75)], atol=1e-6)
    # output 0 sits at source -0.25: taps -2..1 clamp onto the border sample 0
    assert idx[0].tolist() == [0, 0, 0, 1]
    np.testing.assert_allclose(w[0], [k(1.75), k(0.75), k(0.25), k(1.25)], atol=1e-6)
    assert np.allclose(w.sum(1), 1) and math.isclose(k(0), 1)


def _interpolated_texels(features, levels, size, tau, texel):
    """The field as F.interpolate computes it (the resize this project used before its
    matrix form), read at the texels of a channel-major map."""
    out = 0
    for w, s in zip(blend_weights(levels, size, tau), levels, strict=True):
        resized = F.interpolate(
            features[str(s)][None], size=(size, size), mode="bicubic", align_corners=False
        )[0]
        out = out + float(w) * resized
    return out.reshape(out.shape[0], -1)[:, texel].T


@pytest.mark.parametrize("size", [32, 45, 64, 97, 128])
def test_torch_resample_matches_interpolate_forward_and_backward(size):
    levels, tau, c = (128, 64, 32), 0.35, 8
    rng = np.random.default_rng(size)
    texel = torch.from_numpy(np.sort(rng.choice(size * size, size * size // 2, replace=False)))
    features = {
        str(s): torch.from_numpy(rng.normal(size=(c, s, s)).astype(np.float32)).requires_grad_()
        for s in levels
    }
    upstream = torch.from_numpy(rng.normal(size=(len(texel), c)).astype(np.float32))

    def value_and_grads(fn):
        out = fn()
        grads = torch.autograd.grad(out, list(features.values()), upstream)
        return out.detach(), grads

    plan = resample_plan(levels, size, tau, "cpu")
    out, grads = value_and_grads(lambda: texel_features(features, plan, texel))
    ref, ref_grads = value_and_grads(
        lambda: _interpolated_texels(features, levels, size, tau, texel)
    )
    assert out.shape == (len(texel), c) and out.is_contiguous()
    torch.testing.assert_close(out, ref, atol=2e-6, rtol=1e-5)
    for g, r in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(g, r, atol=2e-5, rtol=1e-5)
    # texels nobody reads get no gradient
    unread = torch.ones(size * size, dtype=torch.bool)
    unread[texel] = False
    if size in levels:
        assert grads[levels.index(size)].reshape(c, -1)[:, unread].abs().max() == 0


def test_a_level_at_the_target_size_is_read_as_it_is():
    f = torch.randn(4, 40, 40)
    plan = resample_plan((40,), 40, 0.35, "cpu")
    assert plan == (("40", 1.0, None),)
    texel = torch.tensor([0, 7, 41, 1599])
    out = texel_features({"40": f}, plan, texel)
    assert torch.equal(out, f.reshape(4, -1)[:, texel].T)


@pytest.mark.parametrize("size", [32, 77, 128])
def test_the_kernels_resample_matches_the_matrix_products(size, monkeypatch):
    """Float32 CPU levels go through the splat kernel's taps (csrc/resample.hpp): the same
    field and gradients as the dense products, the same bits at any thread count, and no
    gradient for a level that takes none (stage 4 freezes all but the sparsest)."""
    levels, tau, c = (128, 64, 32), 0.35, 64
    rng = np.random.default_rng(size)
    texel = torch.from_numpy(rng.permutation(size * size)[: size * size * 9 // 10])
    features = {
        str(s): torch.from_numpy(rng.normal(size=(c, s, s)).astype(np.float32)).requires_grad_()
        for s in levels
    }
    upstream = torch.from_numpy(rng.normal(size=(len(texel), c)).astype(np.float32))
    plan = resample_plan(levels, size, tau, "cpu")

    def run(fn):
        out = fn(features, plan, texel)
        return out.detach(), torch.autograd.grad(out, list(features.values()), upstream)

    out, grads = run(texel_features)
    ref, ref_grads = run(texel_features_torch)
    torch.testing.assert_close(out, ref, atol=3e-6, rtol=1e-5)
    for g, r in zip(grads, ref_grads, strict=True):
        torch.testing.assert_close(g, r, atol=3e-5, rtol=1e-5)
    if torch.get_num_threads() > 1:  # the kernel runs on torch's threads
        monkeypatch.setattr(torch, "get_num_threads", lambda: 1)
        one, one_grads = run(texel_features)
        assert torch.equal(one, out)
        assert all(torch.equal(a, b) for a, b in zip(one_grads, grads, strict=True))
    features["128"].requires_grad_(False)
    out = texel_features(features, plan, texel)
    grads = torch.autograd.grad(out, [features["32"], features["64"]], upstream)
    assert all(g.abs().sum() > 0 for g in grads)


def test_the_kernels_resample_refuses_what_it_would_read_past():
    """It reads through raw pointers: texels or taps out of range are refused first."""
    from archhead_addon.avatar.resample import _taps
    from archhead_addon.splat import kernel

    f = np.zeros((4, 8, 8), np.float32)
    out = np.zeros((2, 4), np.float32)
    with pytest.raises(ValueError, match="texels"):
        kernel.resample_forward(f, 16, _taps(8, 16), 1.0, np.array([0, 256]), out)
    bad = (np.full((16, 4), 8, np.int32), np.zeros((16, 4), np.float32))
    with pytest.raises(ValueError, match="taps"):
        kernel.resample_forward(f, 16, bad, 1.0, np.array([0, 255]), out)
    with pytest.raises(ValueError, match="taps"):
        kernel.resample_forward(f, 8, _taps(8, 16), 1.0, np.array([0, 63]), out)
    with pytest.raises(ValueError, match="out"):
        kernel.resample_forward(f, 16, _taps(8, 16), 1.0, np.array([0, 1, 2]), out)
