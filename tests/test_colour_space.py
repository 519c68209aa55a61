"""The sRGB encoding that training applies to its renders: the kernel's one pass
(`linear_to_srgb_torch` on a float32 CPU tensor) against the torch operations and numpy."""

import numpy as np
import pytest
import torch

from archhead_addon.splat.colour_space import (
    linear_to_srgb,
    linear_to_srgb_ops,
    linear_to_srgb_torch,
)

# both sides of every branch and clamp: below 0, 0, the linear part, its end, the curve, 1, above
EDGES = [-0.5, -1e-9, 0.0, 1e-8, 1e-7, 0.001, 0.0031308, 0.0031309, 0.01, 0.5, 0.999, 1.0, 1.0001,
         3.0]  # fmt: skip


def _values(seed=0):
    rng = np.random.default_rng(seed)
    x = np.concatenate([EDGES, rng.uniform(-0.1, 1.1, 70_000), rng.uniform(0, 0.01, 10_000)])
    return torch.from_numpy(x.astype(np.float32))


def test_values_match_the_torch_operations_and_numpy():
    x = _values()
    kernel = linear_to_srgb_torch(x)
    exact = linear_to_srgb(x.numpy().astype(np.float64))
    np.testing.assert_allclose(kernel.numpy(), linear_to_srgb_ops(x).numpy(), rtol=3e-7, atol=1e-7)
    np.testing.assert_allclose(kernel.numpy(), exact, atol=2e-7)
    assert kernel[x <= 0].eq(0).all() and (kernel[x >= 1] - 1).abs().max() < 1e-6


def test_gradient_matches_the_torch_operations():
    x = _values(1)
    away = (x - 0.0031308).abs() > 1e-6  # where() takes one side exactly at the knee
    weights = torch.rand(len(x), generator=torch.Generator().manual_seed(2))
    grads = []
    for fn in (linear_to_srgb_torch, linear_to_srgb_ops):
        leaf = x.clone().requires_grad_(True)
        (fn(leaf) * weights).sum().backward()
        grads.append(leaf.grad)
    np.testing.assert_allclose(grads[0][away].numpy(), grads[1][away].numpy(), rtol=2e-6, atol=1e-7)
    # as torch.clamp's: nothing at either end of [0, 1] or beyond
    outside = (x <= 0) | (x >= 1)
    assert outside.any() and (grads[0][outside] == 0).all() and (grads[0][~outside] > 0).all()
    torch.autograd.gradcheck(
        lambda t: linear_to_srgb_torch(t.float()).double(),
        torch.tensor([0.2, 0.6, 0.002], dtype=torch.float64, requires_grad=True),
        eps=1e-3, atol=1e-3, rtol=1e-2,
    )  # fmt: skip


def test_an_image_as_training_renders_it(monkeypatch):
    """(H, W, 3), not contiguous, any thread count: the same bits."""
    image = torch.rand(3, 64, 48, generator=torch.Generator().manual_seed(3)).permute(1, 2, 0)
    two = linear_to_srgb_torch(image)  # on torch's threads
    monkeypatch.setattr(torch, "get_num_threads", lambda: 1)
    one = linear_to_srgb_torch(image)
    assert one.shape == image.shape and torch.equal(one, two)
    assert torch.equal(one, linear_to_srgb_torch(image.contiguous()))


def test_nan_stays_nan():
    out = linear_to_srgb_torch(torch.tensor([float("nan"), 0.5]))
    assert torch.isnan(out[0]) and out[1] == pytest.approx(0.7354, abs=1e-4)


def test_other_dtypes_take_the_torch_operations():
    x = _values().double()
    assert linear_to_srgb_torch(x).dtype == torch.float64
    exact = linear_to_srgb(x.numpy())
    np.testing.assert_allclose(linear_to_srgb_torch(x).numpy(), exact, atol=1e-12)
