"""The CPU splat kernel against the plain reference renderer, gsplat's PyTorch projection and
gsplat's SH; the public `rasterization()` entry point on the CPU path."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from archhead_addon.splat import kernel, rasterize_frame, scenes
from archhead_addon.splat.frame import SplatFrame
from archhead_addon.splat.reference import render_reference, render_tiles_torch
from archhead_addon.splat.rendering import select_backend
from archhead_addon.splat.sh import sh_to_rgb_numpy, sh_to_rgb_torch

TOL = 1e-5


def float64(a) -> torch.Tensor:
    return torch.tensor(a, dtype=torch.float64)


def reference_image(scene, **kw):
    return render_reference(
        scene.gaussians.map(float64), float64(scene.viewmat), float64(scene.K), scene.width,
        scene.height, **kw,
    )  # fmt: skip


def kernel_image(scene, **kw):
    raster, ctx = kernel.forward(scene.gaussians.checked(), scene.settings(**kw))
    return raster, ctx.stats()


def assert_images_match(raster, ref, tol=TOL):
    np.testing.assert_allclose(raster.rgb, ref.rgb.numpy(), rtol=0, atol=tol)
    np.testing.assert_allclose(raster.alpha, ref.alpha.numpy(), rtol=0, atol=tol)
    depth_scale = max(1.0, float(ref.depth.abs().max()))
    np.testing.assert_allclose(raster.depth, ref.depth.numpy(), rtol=0, atol=tol * depth_scale)


@pytest.mark.parametrize("seed", range(4))
def test_forward_matches_reference_on_random_scenes(seed):
    scene = scenes.random_scene(80, width=40, height=30, seed=seed)
    bg = tuple(np.random.default_rng(seed).uniform(0, 1, 3))
    raster, stats = kernel_image(scene, background=bg)
    assert stats["visible"] > 40 and raster.alpha.max() > 0.9  # a non-trivial image
    assert_images_match(raster, reference_image(scene, background=bg))


@pytest.mark.parametrize("seed", range(2))
def test_forward_matches_reference_on_face_scenes(seed):
    scene = scenes.face_scene(600, width=56, height=48, seed=seed)
    raster, _ = kernel_image(scene, background=(1.0, 1.0, 1.0))
    assert raster.alpha.max() > 0.99  # the head is opaque
    assert_images_match(raster, reference_image(scene, background=(1.0, 1.0, 1.0)))


def test_forward_matches_reference_antialiased():
    scene = scenes.random_scene(80, width=40, height=30, seed=7)
    raster, _ = kernel_image(scene, antialiased=True)
    assert_images_match(raster, reference_image(scene, antialiased=True))


def test_torch_tile_renderer_matches_reference():
    scene = scenes.face_scene(300, width=40, height=36, seed=3)
    tiles = render_tiles_torch(
        scene.gaussians.map(float64), float64(scene.viewmat), float64(scene.K), scene.width,
        scene.height,
    )  # fmt: skip
    ref = reference_image(scene)
    for a, b in zip(tiles, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-9)


def test_projection_matches_gsplat_torch_reference():
    from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci

    rng = np.random.default_rng(0)
    n, width, height = 400, 64, 48
    # Off-centre principal point, non-square pixels, Gaussians on and off screen (so the
    # frustum clamp of the EWA Jacobian is exercised), some behind the near plane.
    K = np.array([[70.0, 0, 25.3], [0, 64.0, 29.1], [0, 0, 1]])
    R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    viewmat = np.eye(4)
    viewmat[:3, :3] = R * np.sign(np.linalg.det(R))
    viewmat[:3, 3] = rng.normal(0, 0.2, 3)
    spread = np.where(rng.uniform(size=(n, 1)) < 0.7, 0.6, 2.5)
    cam = np.concatenate([rng.uniform(-1, 1, (n, 2)) * spread, rng.uniform(-0.2, 4, (n, 1))], 1)
    cam[:, :2] *= cam[:, 2:]
    means = ((cam - viewmat[:3, 3]) @ viewmat[:3, :3]).astype(np.float32)
    quats = rng.normal(size=(n, 4)).astype(np.float32)
    log_scales = rng.uniform(-5, -1, (n, 3)).astype(np.float32)
    logits = rng.uniform(-2, 4, n).astype(np.float32)
    g = SplatFrame(
        means=means, log_scales=log_scales, quats=quats, opacity_logits=logits, sh=np.zeros((n, 3))
    ).checked()

    for antialiased in (False, True):
        settings = kernel.RasterSettings(viewmat, K, width, height, antialiased=antialiased)
        ours = kernel.project(g, settings)
        t = g.map(float64)
        covars, _ = _quat_scale_to_covar_preci(t.quats, t.log_scales.exp(), compute_preci=False)
        radii, means2d, depths, conics, comp = _fully_fused_projection(
            t.means,
            covars,
            torch.tensor(viewmat[None]),
            torch.tensor(K[None]),
            width,
            height,
            calc_compensations=True,
        )
        radii, means2d, depths, conics, comp = (
            x[0].numpy() for x in (radii, means2d, depths, conics, comp)
        )
        ours_vis = ours.radii[:, 0] > 0
        theirs_vis = (radii > 0).all(-1)
        # ours also culls by opacity; its opacity-aware box is never larger than 3.33 sigma
        assert ours_vis.sum() > n // 4 and not (ours_vis & ~theirs_vis).any()
        assert (ours.radii[ours_vis] <= radii[ours_vis]).all()
        np.testing.assert_allclose(ours.means2d[ours_vis], means2d[ours_vis], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(ours.depths[ours_vis], depths[ours_vis], rtol=1e-5)
        np.testing.assert_allclose(
            ours.conics[ours_vis],
            conics[ours_vis],
            rtol=1e-5,
            atol=1e-5 * np.abs(conics[ours_vis]).max(),
        )
        opacity = 1 / (1 + np.exp(-logits.astype(np.float64)))
        expected = opacity * (comp if antialiased else 1.0)
        np.testing.assert_allclose(ours.opacities[ours_vis], expected[ours_vis], rtol=1e-5)


@pytest.mark.parametrize("degree", range(4))
def test_sh_matches_gsplat_and_numpy_matches_torch(degree):
    from gsplat.cuda._torch_impl import _spherical_harmonics

    rng = np.random.default_rng(degree)
    dirs = rng.normal(size=(50, 3)) * rng.uniform(0.1, 10, (50, 1))
    coeffs = rng.normal(size=(50, 16, 3))
    ours_np = sh_to_rgb_numpy(degree, dirs, coeffs)
    ours_t = sh_to_rgb_torch(degree, torch.tensor(dirs), torch.tensor(coeffs)).numpy()
    theirs = torch.clamp_min(
        _spherical_harmonics(degree, torch.tensor(dirs), torch.tensor(coeffs)) + 0.5, 0.0
    )
    np.testing.assert_allclose(ours_np, ours_t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours_np, theirs.numpy(), rtol=0, atol=1e-10)


def test_rasterization_cpu_path_matches_kernel_render():
    scene = scenes.face_scene(500, width=48, height=40, seed=5)
    rng = np.random.default_rng(5)
    sh = rng.normal(0, 0.3, (500, 9, 3)).astype(np.float32)
    bg = (0.2, 0.4, 0.6)
    with_sh = replace(scene.gaussians, sh=sh)
    out = rasterize_frame(
        with_sh.map(torch.tensor), scene.viewmat, scene.K, scene.width, scene.height, background=bg
    )
    assert out.rgb.shape == (40, 48, 3) and out.alpha.shape == out.depth.shape == (40, 48, 1)
    centre = np.linalg.inv(scene.viewmat)[:3, 3]
    means = scene.gaussians.means.astype(np.float64)
    colors = sh_to_rgb_numpy(2, means - centre, sh.astype(np.float64))
    ref = kernel.render_frame(replace(scene.gaussians, sh=colors), scene.settings(background=bg))
    # the kernel evaluates SH coefficients itself, as rasterization does
    np.testing.assert_array_equal(
        kernel.render_frame(with_sh, scene.settings(background=bg)).rgb, ref.rgb
    )
    np.testing.assert_allclose(out.rgb.numpy(), ref.rgb, atol=1e-6)
    np.testing.assert_allclose(out.alpha.numpy()[..., 0], ref.alpha, atol=1e-6)
    np.testing.assert_allclose(out.depth.numpy()[..., 0], ref.depth, rtol=1e-6)
    # expected depth: the camera z of the surface where the head is opaque
    z = out.depth[..., 0][out.alpha[..., 0] > 0.99]
    assert z.numel() > 100 and 0.5 < z.min() and z.max() < 0.6


def test_backend_selection_on_cpu():
    assert select_backend("auto", torch.device("cpu")) == "cpu"
    with pytest.raises(RuntimeError, match="gsplat"):
        select_backend("gsplat", torch.device("cpu"))
    with pytest.raises(ValueError, match="backend"):
        select_backend("cuda", torch.device("cpu"))
