"""Every compositing path this CPU runs (baseline, AVX2, AVX-512: kernel.set_simd) against
the reference renderer, images and gradients, and the paths' images against each other."""

import os
import subprocess
import sys

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


def test_paths_give_bitwise_identical_images():
    """Every lane runs the same float operations, whatever the vector width."""
    scene = scenes.face_scene(3000, width=72, height=56, seed=0)
    images = {}
    for name in kernel.supported_simd():
        kernel.set_simd(name)
        images[name] = render(scene)[0]
    kernel.set_simd("auto")
    first = next(iter(images.values()))
    for name, raster in images.items():
        for a, b in zip(raster, first, strict=True):
            assert np.array_equal(a, b), name


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
