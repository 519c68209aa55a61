"""The paper's loss terms (eq. 6-7) on hand-made inputs, and ST-LPIPS against its package."""

import math

import numpy as np
import pytest
import torch

from archhead_addon.avatar.gaussians import Gaussians
from archhead_addon.train.config import LossWeights
from archhead_addon.train.losses import (
    TrainingLoss,
    huber,
    offset_norm,
    parts_huber,
    scale_norm,
    scale_weight,
)
from archhead_addon.train.perceptual import ShiftTolerantLPIPS, unfolded


@pytest.fixture(scope="module")
def st_lpips():
    return ShiftTolerantLPIPS()


def gaussians(offsets, scales):
    n = len(offsets)
    return Gaussians(
        means=torch.zeros(n, 3),
        log_scales=torch.log(torch.tensor(scales)),
        quats=torch.tensor([[1.0, 0, 0, 0]] * n),
        opacity_logits=torch.zeros(n),
        sh=torch.zeros(n, 16, 3),
        offsets=torch.tensor(offsets),
        uv_texel=torch.arange(n),
        resolution=4,
    )


def test_huber_is_quadratic_below_delta_and_linear_above():
    pred = torch.tensor([0.05, 0.3, -0.2, 0.0])
    target = torch.zeros(4)
    # 0.5 * 0.05², 0.1 * (0.3 - 0.05), 0.1 * (0.2 - 0.05), 0
    expected = (0.00125 + 0.025 + 0.015 + 0.0) / 4
    assert float(huber(pred, target, 0.1)) == pytest.approx(expected, rel=1e-6)
    assert float(huber(pred, target, 1.0)) == pytest.approx(
        0.5 * (0.05**2 + 0.3**2 + 0.2**2) / 4, rel=1e-6
    )


def test_parts_term_counts_only_masked_pixels_averaged_over_the_whole_image():
    target = torch.zeros(2, 2, 3)
    pred = torch.zeros(2, 2, 3)
    pred[0, 0] = 0.05  # inside the mask: 0.5 * 0.05² per channel
    pred[1, 1] = 0.9  # outside: ignored
    parts = torch.tensor([[1.0, 0.0], [0.0, 0.0]])
    assert float(parts_huber(pred, target, parts, 0.1)) == pytest.approx(
        3 * 0.5 * 0.05**2 / 12, rel=1e-6
    )


@pytest.mark.parametrize("delta", [0.1, 1.0])
def test_image_terms_by_the_kernel_match_the_torch_operations(delta, monkeypatch):
    """On float32 CPU images the two image terms take the splat kernel's one pass: the same
    values and gradients as `huber` and `parts_huber`, both sides of delta, any threads."""
    gen = torch.Generator().manual_seed(0)
    target = torch.rand(96, 80, 3, generator=gen)
    pred = (target + 0.3 * torch.randn(96, 80, 3, generator=gen)).clamp(0, 1)
    parts = (torch.rand(96, 80, generator=gen) > 0.7).float() * torch.rand(96, 80, generator=gen)
    loss = TrainingLoss(LossWeights(huber_delta=delta))
    weights = (0.7, 20.0)
    results = []

    def on_one_thread(p):  # the kernel runs on torch's threads
        monkeypatch.setattr(torch, "get_num_threads", lambda: 1)
        return loss.image_terms(p, target, parts)

    for terms in (
        lambda p: loss.image_terms(p, target, parts),
        lambda p: (huber(p, target, delta), parts_huber(p, target, parts, delta)),
        on_one_thread,
    ):
        leaf = pred.clone().requires_grad_(True)
        values = terms(leaf)
        (weights[0] * values[0] + weights[1] * values[1]).backward()
        results.append(([float(v.detach()) for v in values], leaf.grad))
    (kernel, k_grad), (ops, o_grad), (one_thread, t_grad) = results
    assert kernel == pytest.approx(ops, rel=1e-5) and min(ops) > 0
    assert kernel == one_thread and torch.equal(k_grad, t_grad)
    np.testing.assert_allclose(k_grad.numpy(), o_grad.numpy(), rtol=1e-5, atol=1e-12)
    if delta < 1:  # some differences past delta: the linear side's gradient
        assert ((pred - target).abs() > delta).any()


def test_image_terms_of_other_dtypes_take_the_torch_operations():
    image = torch.rand(4, 5, 3, dtype=torch.float64)
    parts = torch.ones(4, 5, dtype=torch.float64)
    rgb, part = TrainingLoss(LossWeights()).image_terms(image, image * 0.5, parts)
    assert rgb.dtype == torch.float64 and float(rgb) == pytest.approx(float(part))


def test_offset_and_scale_terms_are_mean_l2_norms():
    g = gaussians(
        offsets=[[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]], scales=[[1.0, 2.0, 2.0], [0.0, 0.0, 1.0]]
    )
    assert float(offset_norm(g.offsets)) == pytest.approx(2.5)
    assert float(scale_norm(g.log_scales)) == pytest.approx(2.0)  # (3 + 1) / 2


def test_scale_weight_halves_from_the_densest_to_the_sparsest_level():
    w = LossWeights()
    assert (w.parts, w.lpips, w.offset, w.scale) == (20.0, 0.05, 0.001, 0.5)  # the paper's
    assert scale_weight(w, 0.0) == 0.5
    assert scale_weight(w, 0.5) == 0.375
    assert scale_weight(w, 1.0) == 0.25


def test_total_is_the_weighted_sum_of_eq_6():
    weights = LossWeights(parts=20.0, lpips=0.0, offset=0.001, scale=0.5, huber_delta=0.1)
    target = torch.zeros(2, 2, 3)
    pred = torch.full((2, 2, 3), 0.05)
    parts = torch.tensor([[1.0, 1.0], [0.0, 0.0]])
    g = gaussians([[3.0, 4.0, 0.0]], [[1.0, 2.0, 2.0]])
    total, terms = TrainingLoss(weights)(pred, target, parts, g, lod=1.0)
    rgb = 0.5 * 0.05**2
    expected = rgb + 20 * rgb / 2 + 0.001 * 5.0 + 0.25 * 3.0
    assert float(total) == pytest.approx(expected, rel=1e-6)
    assert terms["rgb"] == pytest.approx(rgb, rel=1e-6)
    assert terms["parts"] == pytest.approx(rgb / 2, rel=1e-6)
    assert terms["total"] == pytest.approx(expected, rel=1e-6)
    assert "lpips" not in terms


def test_gradient_reaches_the_render_and_the_gaussians(st_lpips):
    pred = torch.full((40, 40, 3), 0.3, requires_grad=True)
    target = torch.rand(40, 40, 3, generator=torch.Generator().manual_seed(0))
    g = gaussians([[0.01, 0.0, 0.0]], [[0.01, 0.01, 0.01]])
    g.offsets.requires_grad_(True)
    total, terms = TrainingLoss(LossWeights(), st_lpips)(
        pred, target, torch.ones(40, 40), g, lod=0.0
    )
    total.backward()
    assert terms["lpips"] > 0
    assert pred.grad.abs().sum() > 0 and g.offsets.grad.abs().sum() > 0


def reference_images(h=64, w=80):
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    a = np.stack(
        [0.5 + 0.4 * np.sin(7 * xx + 3 * yy), 0.5 + 0.4 * np.cos(5 * yy - 2 * xx), xx * yy], 0
    )
    b = np.roll(a, 1, axis=2) * 0.9 + 0.05
    c = a + 0.1 * np.sin(40 * xx)[None]
    return [torch.tensor(x[None], dtype=torch.float32).clamp(0, 1) for x in (a, b, c)]


def test_st_lpips_matches_the_package_implementation(st_lpips):
    # computed with stlpips_pytorch 0.0.2's own code:
    # stlpips.LPIPS(net="alex", variant="shift_tolerant")(x, y, normalize=True)
    expected = [0.006129368208348751, 0.1363798975944519, 0.14596176147460938]
    a, b, c = reference_images()
    with torch.no_grad():
        got = [float(st_lpips(a, b)), float(st_lpips(a, c)), float(st_lpips(b, c))]
        assert float(st_lpips(a, a)) == 0.0
    assert got == pytest.approx(expected, rel=1e-5)
    # tolerant of a one-pixel shift (b), not of a stripe pattern (c)
    assert got[0] < got[1] / 10


def test_st_lpips_gradient_matches_the_library_convolution(st_lpips):
    """The folded first slice with its row-by-row input gradient against torch's own
    convolution and backward; a shared reference gives the distance that the pair does."""
    a, b, _ = reference_images()
    plain = unfolded(st_lpips)
    grads = []
    for module in (st_lpips, plain):
        x = a.clone().requires_grad_(True)
        module(x, b).sum().backward()
        grads.append(x.grad)
    assert grads[0].abs().max() > 0
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-4, atol=1e-7)

    reference = st_lpips.reference(b)
    assert not any(f.requires_grad for f in reference.features)
    torch.testing.assert_close(st_lpips.compare(a, reference), st_lpips(a, b))
    with pytest.raises(ValueError, match="two"):
        st_lpips.compare(a[..., :-1], reference)


@pytest.mark.parametrize("size", [(32, 32), (34, 40), (64, 80), (256, 256), (35, 48)])
def test_the_folded_first_slice_is_the_plain_one(st_lpips, size):
    """Folding the blur into the first convolution changes nothing but round-off, at the
    reflected edges too; an odd size takes the plain way."""
    plain = unfolded(st_lpips).trunk[0]
    x = torch.rand(2, 3, *size, generator=torch.Generator().manual_seed(sum(size)))
    outputs, grads = [], []
    for layer in (st_lpips.trunk[0], plain):
        xi = x.clone().requires_grad_(True)
        y = layer(xi)
        (y * torch.linspace(-1, 1, y.numel()).reshape(y.shape)).sum().backward()
        outputs.append(y)
        grads.append(xi.grad)
    assert outputs[0].shape == outputs[1].shape
    assert outputs[1].abs().max() > 0.1 and grads[1].abs().max() > 0.01
    torch.testing.assert_close(outputs[0], outputs[1], rtol=1e-5, atol=2e-5)
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-5, atol=2e-5)


def test_st_lpips_rejects_small_or_mismatched_images(st_lpips):
    with pytest.raises(ValueError, match="32x32"):
        st_lpips(torch.zeros(1, 3, 16, 16), torch.zeros(1, 3, 16, 16))
    with pytest.raises(ValueError, match="two"):
        st_lpips(torch.zeros(1, 3, 40, 40), torch.zeros(1, 3, 40, 41))
    assert not any(p.requires_grad for p in st_lpips.parameters())
    assert math.isfinite(float(st_lpips(torch.zeros(1, 3, 32, 32), torch.ones(1, 3, 32, 32))))


def test_anisotropy_pulls_only_on_needles():
    from archhead_addon.train.losses import anisotropy_excess

    round_ish = torch.log(torch.tensor([[1e-3, 2e-3, 5e-3]]))  # ratio 5: no needle
    needle = torch.log(torch.tensor([[1e-4, 1e-3, 5e-3]]))  # ratio 50
    log_scales = torch.cat([round_ish, needle]).requires_grad_(True)
    excess = anisotropy_excess(log_scales)
    assert float(excess.detach()) == pytest.approx((math.log(50) - math.log(10)) / 2)
    excess.backward()
    assert log_scales.grad[0].abs().sum() == 0
    assert log_scales.grad[1].tolist() == pytest.approx([-0.5, 0.0, 0.5])


def test_the_rod_penalty_pulls_on_rods_and_leaves_discs():
    from archhead_addon.train.losses import rod_excess

    disc = torch.log(torch.tensor([[1e-4, 5e-3, 5e-3]]))  # flat, two long axes: a surface
    rod = torch.log(torch.tensor([[1e-3, 1e-3, 6e-3]]))  # longest 6x the middle: a dash
    log_scales = torch.cat([disc, rod]).requires_grad_(True)
    excess = rod_excess(log_scales)
    assert float(excess.detach()) == pytest.approx((math.log(6) - math.log(3)) / 2, rel=1e-5)
    excess.backward()
    assert log_scales.grad[0].abs().sum() == 0
    # the longest axis shrinks and the middle one grows (ties share the middle's pull)
    assert log_scales.grad[1, 2] == pytest.approx(0.5)
    assert float(log_scales.grad[1, :2].sum()) == pytest.approx(-0.5)


def test_the_huber_threshold_must_be_positive():
    from archhead_addon.io.errors import InputError
    from archhead_addon.train.config import TrainConfig

    with pytest.raises(InputError, match="loss.huber_delta"):
        TrainConfig.read({"loss": {"huber_delta": 0}}, "run.json")
