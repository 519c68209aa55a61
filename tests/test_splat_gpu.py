"""On a CUDA machine, training renders with gsplat; its image of a face-like scene agrees with
the CPU kernel's (the same projection and blending conventions). Skipped without CUDA."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from archhead_addon.splat import rasterize_frame, scenes
from archhead_addon.splat.rendering import gsplat_available, select_backend

pytestmark = pytest.mark.gpu


def test_gsplat_on_cuda_agrees_with_the_cpu_kernel():
    if not gsplat_available():
        pytest.skip("gsplat is not installed")
    cuda = torch.device("cuda")
    assert select_backend("auto", cuda) == "gsplat"
    scene = scenes.face_scene(500, width=48, height=40, seed=5)
    sh = np.random.default_rng(5).normal(0, 0.3, (500, 9, 3)).astype(np.float32)
    frame = replace(scene.gaussians, sh=sh)
    args = (scene.viewmat, scene.K, scene.width, scene.height)
    cpu = rasterize_frame(frame.map(torch.tensor), *args)
    gpu = rasterize_frame(frame.map(lambda a: torch.tensor(a, device=cuda)), *args)
    np.testing.assert_allclose(gpu.alpha.cpu().numpy(), cpu.alpha.numpy(), atol=2e-2)
    np.testing.assert_allclose(gpu.rgb.cpu().numpy(), cpu.rgb.numpy(), atol=2e-2)
