"""Every compositing path this CPU runs (baseline, AVX2, AVX-512: kernel.set_simd) against
the reference renderer, images and gradients, and the paths' images against each other."""

import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from test_splat_gradients import assert_grads_match, kernel_grads, loss_weights, reference_grads
from test_splat_reference import assert_images_match, reference_image

from archhead_addon.splat import kernel, scenes

PATHS = [name for name in kernel.SIMD if name != "auto"]


@pytest.fixture(params=PATHS)
def simd(request):
    if request.param not in kernel.supported_simd():
        pytest.skip(f"this CPU has no {request.param}")
    kernel.set_simd(request.param)
    yield request.param
    kernel.set_simd("auto")


def render(scene, **kw):
    raster, ctx = kernel.forward(scene.gaussians.checked(), scene.settings(**kw))
    return raster, ctx.stats()["simd"]


@pytest.mark.parametrize("make_scene", [
    lambda: scenes.random_scene(80, width=40, height=30, seed=3),
    lambda: scenes.face_scene(600, width=56, height=48, seed=1),
])  # fmt: skip
def test_images_match_reference(simd, make_scene):
    scene = make_scene()
    raster, used = render(scene, background=(0.2, 0.4, 0.6))
    assert used == simd
    assert_images_match(raster, reference_image(scene, background=(0.2, 0.4, 0.6)))


def test_gradients_match_reference(simd):
    scene = scenes.face_scene(400, width=40, height=36, seed=2)
    weights = loss_weights(36, 40, 2)
    assert_grads_match(kernel_grads(scene, weights), reference_grads(scene, weights))


def test_gradients_match_reference_antialiased(simd):
    scene = scenes.random_scene(40, width=32, height=24, seed=5)
    weights = loss_weights(24, 32, 5)
    kw = dict(antialiased=True)
    assert_grads_match(kernel_grads(scene, weights, **kw), reference_grads(scene, weights, **kw))


def test_paths_agree():
    """The FMA paths (AVX2, AVX-512) run the same fused float operations whatever the vector
    width and tile size (16 and 32 pixels): bitwise identical images. The baseline path
    (SSE2 has no FMA) rounds products separately: round-off, or one sample that a rounding
    takes across the 1/255 alpha threshold."""
    scene = scenes.face_scene(3000, width=72, height=56, seed=0)
    images = {}
    for name in kernel.supported_simd():
        kernel.set_simd(name)
        images[name] = render(scene)[0]
    kernel.set_simd("auto")
    baseline = images.pop("baseline")
    if not images:
        pytest.skip("this CPU has no FMA path")
    first = next(iter(images.values()))
    for name, raster in images.items():
        for a, b in zip(raster, first, strict=True):
            assert np.array_equal(a, b), name
    for a, b in zip(baseline, first, strict=True):
        diff = np.abs(a - b)
        assert diff.max() <= 1 / 255 + 1e-6 and diff.mean() <= 1e-6


def test_unknown_or_unsupported_path_is_refused():
    with pytest.raises(ValueError, match="unknown splat SIMD"):
        kernel.set_simd("neon")
    assert kernel.set_simd("auto") == kernel.supported_simd()[-1]


def test_environment_variable_forces_a_path():
    code = (
        "from archhead_addon.splat import kernel, scenes\n"
        "s = scenes.random_scene(5)\n"
        "print(kernel.forward(s.gaussians.checked(), s.settings())[1].stats()['simd'])\n"
    )
    env = {**os.environ, kernel.SIMD_ENV: "baseline"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert out.stdout.strip() == "baseline", out.stderr


def thin_faint_scene(n, width, height, seed):
    """random_scene with needle-thin and very elongated Gaussians at every angle, some far
    longer than the image, opacities from just above 1/255 to nearly opaque: the cases where
    an ellipse's bounds could drop a lane that composites."""
    scene = scenes.random_scene(n, width, height, seed=seed)
    rng = np.random.default_rng(seed)
    g = scene.gaussians
    log_scales = g.log_scales.copy()
    log_scales[:, 0] += rng.choice([0.0, 2.0, 4.0, 7.0], n)  # up to 1000x longer
    log_scales[:, 1] -= rng.choice([0.0, 3.0, 8.0], n)  # down to the 0.3 px² dilation
    opacity = rng.choice([1 / 254, 1 / 200, 0.02, 0.5, 0.999], n)
    logits = np.log(opacity / (1 - opacity)) + rng.normal(0, 1e-3, n)
    frame = replace(g, log_scales=log_scales, opacity_logits=logits)
    return scene._replace(gaussians=frame.map(lambda a: np.asarray(a, np.float32)))


def ellipse_and_box(scene, seed):
    """Images, gradients and stats() with the ellipse's steps, then with the box's."""
    h, w = scene.height, scene.width
    rng = np.random.default_rng(seed)
    grads_out = (rng.normal(size=(h, w, 3)), rng.normal(size=(h, w)), rng.normal(size=(h, w)))
    results = []
    for ellipse in (True, False):
        kernel.set_ellipse_steps(ellipse)
        try:
            raster, ctx = kernel.forward(scene.gaussians.checked(), scene.settings())
        finally:
            kernel.set_ellipse_steps(True)
        grads = kernel.backward(ctx, *grads_out).arrays().values()
        results.append(([*raster, *grads], ctx.stats()))
    return results


@pytest.mark.parametrize("make_scene", [
    lambda seed: thin_faint_scene(300, 48, 40, seed),
    lambda seed: scenes.face_scene(2000, 64, 56, seed=seed),
])  # fmt: skip
@pytest.mark.parametrize("seed", range(3))
def test_ellipse_steps_give_the_box_results(simd, make_scene, seed):
    """Skipping the steps outside each ellipse leaves images and gradients bitwise equal
    and composites every sample the whole box did, with fewer lanes evaluated."""
    (ours, ours_stats), (box, box_stats) = ellipse_and_box(make_scene(seed), seed)
    for a, b in zip(ours, box, strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    assert ours_stats["lanes_used"] == box_stats["lanes_used"] > 0
    assert ours_stats["lanes_evaluated"] < box_stats["lanes_evaluated"]
