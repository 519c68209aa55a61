"""The 3DGS numerics rules of the CPU kernel, one test each, on scenes small enough to
predict by hand; plus validation, degenerate inputs and thread-count determinism."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from archhead_addon import threads as thread_counts
from archhead_addon.splat import kernel, rasterization, scenes
from archhead_addon.splat.frame import FIELDS, SplatFrame
from archhead_addon.splat.reference import render_reference

FOCAL = 10.0


def camera(width=5, height=5, cx=None, cy=None, fx=FOCAL, fy=FOCAL):
    cx = width / 2 if cx is None else cx
    cy = height / 2 if cy is None else cy
    return np.eye(4), np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def gaussians(means, log_scales=-30.0, logits=0.0, colors=(1.0, 0.5, 0.25), quats=(1, 0, 0, 0)):
    means = np.atleast_2d(np.asarray(means, np.float64))
    n = len(means)

    def rows(x, k):
        return np.broadcast_to(np.asarray(x, np.float64), (n, k)).copy()

    logits = np.broadcast_to(np.asarray(logits, np.float64), (n,))
    return SplatFrame(
        means=means,
        log_scales=rows(log_scales, 3),
        quats=rows(quats, 4),
        opacity_logits=logits,
        sh=rows(colors, 3),
    ).checked()


def render(g, width=5, height=5, cam=None, **kw):
    viewmat, K = cam if cam is not None else camera(width, height)
    settings = kernel.RasterSettings(viewmat, K, width, height, **kw)
    return kernel.forward(g, settings)


def reference(g, width, height, cam, **kw):
    viewmat, K = (torch.tensor(a) for a in cam)
    return render_reference(
        g.map(lambda a: torch.tensor(a, dtype=torch.float64)), viewmat, K, width, height, **kw
    )


def assert_matches_reference(g, width, height, cam, **kw):
    (rgb, alpha, depth), _ = render(g, width, height, cam, **kw)
    ref = reference(g, width, height, cam, **kw)
    np.testing.assert_allclose(rgb, ref.rgb.numpy(), atol=1e-5, rtol=0)
    np.testing.assert_allclose(alpha, ref.alpha.numpy(), atol=1e-5, rtol=0)
    np.testing.assert_allclose(depth, ref.depth.numpy(), atol=1e-5, rtol=1e-5)


def backward_ones(ctx):
    h, w = ctx.shape
    return kernel.backward(ctx, np.ones((h, w, 3)), np.ones((h, w)), np.ones((h, w)))


def sigmoid32(logit):
    return np.float32(1 / (1 + np.exp(-np.float64(logit))))


ON_AXIS = (0.0, 0.0, 1.0)  # projects onto the centre of pixel (2, 2) of the 5x5 camera


def test_covariance_dilated_by_0p3_px2():
    # A point-like Gaussian is the dilation kernel alone: alpha = o exp(-d^2 / (2 * 0.3)).
    (_, alpha, _), _ = render(gaussians(ON_AXIS))
    assert alpha[2, 2] == pytest.approx(0.5, abs=1e-6)
    assert alpha[2, 3] == pytest.approx(0.5 * np.exp(-0.5 / 0.3), abs=1e-6)
    assert alpha[3, 3] == pytest.approx(0.5 * np.exp(-1.0 / 0.3), abs=1e-6)
    assert alpha[2, 4] == 0.0  # 0.5 exp(-4 / 0.6) < 1/255
    (_, alpha, _), _ = render(gaussians(ON_AXIS), eps2d=1.0)
    assert alpha[2, 3] == pytest.approx(0.5 * np.exp(-0.5), abs=1e-6)


def test_antialiased_opacity_compensation():
    sigma_px = 1.0  # isotropic: cov2d = I, dilated 1.3 I, compensation sqrt(1 / 1.3^2)
    g = gaussians(ON_AXIS, log_scales=np.log(sigma_px / FOCAL))
    (_, classic, _), _ = render(g)
    (_, aa, _), _ = render(g, antialiased=True)
    assert classic[2, 2] == pytest.approx(0.5, abs=1e-6)
    assert aa[2, 2] == pytest.approx(0.5 / 1.3, abs=1e-6)
    assert aa[2, 3] == pytest.approx(0.5 / 1.3 * np.exp(-0.5 / 1.3), abs=1e-6)
    # a point-like Gaussian is compensated to nothing
    (_, alpha, _), _ = render(gaussians(ON_AXIS), antialiased=True)
    assert not alpha.any()


def test_alpha_clamped_at_0p99():
    bg = np.array([0.2, 0.4, 0.6])
    g = gaussians(ON_AXIS, log_scales=np.log(0.5), logits=50.0)  # opacity 1, covers the image
    (rgb, alpha, _), _ = render(g, background=tuple(bg))
    np.testing.assert_allclose(alpha[2, 2], 0.99, atol=1e-6)
    np.testing.assert_allclose(rgb[2, 2], 0.99 * np.array([1.0, 0.5, 0.25]) + 0.01 * bg, atol=1e-6)


def test_samples_below_1_over_255_skipped():
    logit = np.log((1.001 / 255) / (1 - 1.001 / 255))  # centre alpha just above 1/255
    (rgb, alpha, _), _ = render(gaussians(ON_AXIS, logits=logit), background=(0.3, 0.3, 0.3))
    assert alpha[2, 2] == pytest.approx(1.001 / 255, rel=1e-5)
    alpha[2, 2] = 0.0
    assert not alpha.any()  # neighbours: 1.001/255 * 0.19 < 1/255, skipped, exactly zero
    logit = np.log((0.999 / 255) / (1 - 0.999 / 255))
    (rgb, alpha, _), _ = render(gaussians(ON_AXIS, logits=logit), background=(0.3, 0.3, 0.3))
    assert not alpha.any() and (rgb == np.float32(0.3)).all()


def test_pixel_stops_below_transmittance_1e_4():
    # Five Gaussians on the same pixel centre, alpha 0.95 each: T = 0.05, 0.0025, 1.25e-4,
    # then 6.25e-6 < 1e-4, so the fourth stops the pixel and only three contribute.
    colors = np.eye(5, 3)
    logit = np.log(0.95 / 0.05)
    means = [(0.0, 0.0, z) for z in (1.0, 1.5, 2.0, 2.5, 3.0)]
    g = gaussians(means, log_scales=np.log(0.5), logits=logit, colors=colors)
    (rgb, alpha, depth), ctx = render(g)
    o = sigmoid32(logit)
    T = [1.0, 1 - o, (1 - o) ** 2, (1 - o) ** 3]
    expected = sum(colors[k] * o * T[k] for k in range(3))
    np.testing.assert_allclose(rgb[2, 2], expected, atol=1e-6)
    assert alpha[2, 2] == pytest.approx(1 - T[3], abs=1e-6)
    assert depth[2, 2] == pytest.approx(o * (1.0 * T[0] + 1.5 * T[1] + 2.0 * T[2]), rel=1e-6)
    g_rgb = np.zeros((5, 5, 3))
    g_rgb[2, 2] = 1.0
    grads = kernel.backward(ctx, g_rgb)
    assert grads.sh[:3].all() and not grads.sh[3:].any()  # stopped: no gradient
    assert_matches_reference(g, 5, 5, camera())


def test_depth_order_finer_than_float32():
    # Depths 3 - 1e-8 and 3 + 1.1e-7 round to the same float32: still front to back.
    viewmat, K = camera()
    viewmat[2, 3] = 2.0 - 1e-8
    front, back = (0.0, 0.0, 1.0), (0.0, 0.0, float(np.nextafter(np.float32(1), np.float32(2))))
    red, green = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
    for means, colors in (([front, back], [red, green]), ([back, front], [green, red])):
        g = gaussians(means, log_scales=np.log(0.5), colors=colors)  # opacity 0.5 each
        (rgb, _, _), _ = render(g, cam=(viewmat, K))
        np.testing.assert_allclose(rgb[2, 2], [0.5, 0.25, 0.0], atol=1e-6)


def test_near_and_far_planes_cull():
    cam = camera(width=8, height=1)
    # pixels 0..3 left to right at depths 0.45 | 0.55 | 1.95 | 2.05, each on its pixel centre
    zs = np.array([0.45, 0.55, 1.95, 2.05])
    u = np.array([0.5, 2.5, 4.5, 6.5])
    means = np.stack([(u - 4.0) * zs / FOCAL, np.zeros(4), zs], -1)
    (_, alpha, _), _ = render(gaussians(means), 8, 1, cam, near_plane=0.5, far_plane=2.0)
    assert alpha[0, [0, 6]].tolist() == [0.0, 0.0]
    assert alpha[0, 2] == pytest.approx(0.5, abs=1e-6) and alpha[0, 4] == pytest.approx(0.5)
    assert_matches_reference(gaussians(means), 8, 1, cam, near_plane=0.5, far_plane=2.0)


def test_gaussians_behind_or_at_the_camera_centre():
    g = gaussians([(0.0, 0.0, -1.0), (0.0, 0.0, 0.0), (1e-3, 0.0, 0.0)], log_scales=0.0, logits=5.0)
    (rgb, alpha, depth), ctx = render(g, background=(0.1, 0.2, 0.3))
    assert not alpha.any() and not depth.any()
    np.testing.assert_array_equal(rgb, np.broadcast_to(np.float32([0.1, 0.2, 0.3]), rgb.shape))
    for grad in backward_ones(ctx).arrays().values():
        assert np.isfinite(grad).all() and not grad.any()


@pytest.mark.parametrize(
    "log_scale", [-1e30, np.log(1e-8), np.log(1e4)], ids=["scale0", "scale1e-8", "scale1e4"]
)
def test_extreme_scales(log_scale):
    g = gaussians(ON_AXIS, log_scales=log_scale, logits=1.0)
    (rgb, alpha, depth), ctx = render(g)
    o = sigmoid32(1.0)
    assert alpha[2, 2] == pytest.approx(o, abs=1e-6)
    if log_scale > 0:  # a 1e4 m Gaussian seen from 1 m covers the image uniformly
        np.testing.assert_allclose(alpha, o, atol=1e-6)
    else:  # a vanishing one is the dilation kernel alone
        assert alpha[2, 3] == pytest.approx(o * np.exp(-0.5 / 0.3), abs=1e-6)
    grads = backward_ones(ctx).arrays().values()
    assert all(np.isfinite(x).all() for x in (rgb, alpha, depth, *grads))
    assert_matches_reference(g, 5, 5, camera())


def test_scale_ratio_1e4():
    rng = np.random.default_rng(0)
    n = 12
    means = np.stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.2, 0.2, n),
                      rng.uniform(0.8, 1.5, n)], -1)  # fmt: skip
    s = np.log(0.05)
    log_scales = np.stack([np.full(n, s), np.full(n, s + np.log(1e-4)), np.full(n, s)], -1)
    g = gaussians(
        means, log_scales, rng.normal(1, 1, n), rng.uniform(0, 1, (n, 3)), rng.normal(size=(n, 4))
    )
    (_, alpha, _), ctx = render(g, 9, 9, camera(9, 9))
    assert alpha.max() > 0.5
    assert all(np.isfinite(x).all() for x in backward_ones(ctx).arrays().values())
    assert_matches_reference(g, 9, 9, camera(9, 9))


def test_zero_quaternion_is_the_identity():
    scales = np.log([0.3, 0.1, 0.05])
    a, ctx = render(gaussians(ON_AXIS, scales, quats=(0, 0, 0, 0)), 9, 9, camera(9, 9))
    b, _ = render(gaussians(ON_AXIS, scales, quats=(1, 0, 0, 0)), 9, 9, camera(9, 9))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    grads = backward_ones(ctx)
    assert all(np.isfinite(x).all() for x in grads.arrays().values()) and grads.log_scales.any()


def test_opacity_logits_saturate():
    big = np.log(0.5)
    (_, a50, _), ctx = render(gaussians(ON_AXIS, big, logits=50.0))
    (_, a30, _), _ = render(gaussians(ON_AXIS, big, logits=30.0))
    np.testing.assert_array_equal(a50, a30)  # opacity exactly 1 in float32
    assert a50[2, 2] == pytest.approx(0.99, abs=1e-6)
    assert np.isfinite(backward_ones(ctx).opacity_logits).all()
    (_, a, _), ctx = render(gaussians(ON_AXIS, big, logits=-50.0))  # opacity ~0: culled
    assert not a.any() and ctx.stats()["visible"] == 0


def test_no_gaussians():
    g = gaussians(np.zeros((0, 3)))
    (rgb, alpha, depth), ctx = render(g, 7, 3, camera(7, 3), background=(0.5, 0.25, 1.0))
    assert (rgb == np.float32([0.5, 0.25, 1.0])).all() and not alpha.any() and not depth.any()
    shapes = {name: x.shape for name, x in backward_ones(ctx).arrays().items()}
    assert shapes == {"means": (0, 3), "log_scales": (0, 3), "quats": (0, 4),
                      "opacity_logits": (0,), "sh": (0, 3)}  # fmt: skip


def test_one_by_one_image():
    scene = scenes.random_scene(20, width=1, height=1, seed=3)
    g = scene.gaussians.checked()
    assert_matches_reference(g, 1, 1, (scene.viewmat, scene.K), background=(0.2, 0.2, 0.2))


def test_non_square_image():
    width, height = 37, 13
    scene = scenes.random_scene(60, width=width, height=height, seed=5)
    g = scene.gaussians.checked()
    assert_matches_reference(g, width, height, (scene.viewmat, scene.K))


def test_off_centre_principal_point():
    width, height = 37, 13
    cam = camera(width, height, cx=5.3, cy=10.1, fx=12.0, fy=9.0)
    # a point-like Gaussian lands on the pixel containing K @ X
    x = np.array([0.7, -0.35, 1.3])
    u, v = 12.0 * x[0] / x[2] + 5.3, 9.0 * x[1] / x[2] + 10.1
    (_, alpha, _), _ = render(gaussians(x), width, height, cam)
    assert np.unravel_index(alpha.argmax(), alpha.shape) == (int(v), int(u))
    scene = scenes.random_scene(60, width=width, height=height, seed=6)
    g = scene.gaussians.checked()
    assert_matches_reference(g, width, height, cam)


@pytest.mark.parametrize("name", FIELDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_inputs_rejected(name, bad):
    g = gaussians([ON_AXIS] * 3).map(lambda a: np.array(a, np.float64))
    getattr(g, name).flat[-1] = bad
    with pytest.raises(ValueError, match=name):
        g.checked()
    t = g.map(lambda a: torch.tensor(a, dtype=torch.float32))
    viewmat, K = camera()
    with pytest.raises(ValueError, match=name):  # the gsplat-order entry point names it too
        rasterization(
            means=t.means,
            quats=t.quats,
            log_scales=t.log_scales,
            opacity_logits=t.opacity_logits,
            colors=t.sh,
            viewmat=viewmat,
            K=K,
            width=5,
            height=5,
        )


def test_kernel_takes_checked_frames_only():
    g = gaussians([ON_AXIS] * 3)
    with pytest.raises(ValueError, match="checked"):
        render(replace(g, quats=g.quats.astype(np.float64)))
    with pytest.raises(ValueError, match="sh"):  # SH coefficients: render_frame evaluates them
        render(replace(g, sh=np.zeros((3, 4, 3), np.float32)))


def test_non_finite_or_invalid_camera_rejected():
    g = gaussians(ON_AXIS)
    viewmat, K = camera()
    bad_view = viewmat.copy()
    bad_view[0, 3] = np.nan
    with pytest.raises(ValueError, match="viewmat"):
        render(g, cam=(bad_view, K))
    bad_K = K.copy()
    bad_K[0, 0] = np.inf
    with pytest.raises(ValueError, match="K"):
        render(g, cam=(viewmat, bad_K))
    skew = K.copy()
    skew[0, 1] = 0.5
    with pytest.raises(ValueError, match="skew"):
        render(g, cam=(viewmat, skew))
    projective = viewmat.copy()
    projective[3, 2] = 1.0
    with pytest.raises(ValueError, match="last row"):
        render(g, cam=(projective, K))
    with pytest.raises(ValueError, match="background"):
        render(g, background=(0, np.nan, 0))
    with pytest.raises(ValueError, match="near_plane"):
        render(g, near_plane=0.0)
    with pytest.raises(ValueError, match="width"):
        render(g, width=0)


def test_forward_without_backward_state():
    scene = scenes.face_scene(2000, width=48, height=40, seed=3)
    g, settings = scene.gaussians.checked(), scene.settings()
    full, _ = kernel.forward(g, settings)
    image, ctx = kernel.forward(g, settings, for_backward=False)
    for a, b in zip(full, image, strict=True):
        assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="for_backward"):
        kernel.backward(ctx, np.ones((40, 48, 3)))


def test_same_result_for_any_thread_count(monkeypatch):
    monkeypatch.setattr(thread_counts, "machine_cores", lambda: 3)  # 3 threads even on 2 cores
    scene = scenes.face_scene(4000, width=96, height=80, seed=2)
    g = scene.gaussians.checked()
    rng = np.random.default_rng(0)
    grads_out = (rng.normal(size=(80, 96, 3)), rng.normal(size=(80, 96)),
                 rng.normal(size=(80, 96)))  # fmt: skip
    results = []
    for threads in (1, 2, 3):
        settings = kernel.RasterSettings(scene.viewmat, scene.K, 96, 80, num_threads=threads)
        raster, ctx = kernel.forward(g, settings)
        results.append((*raster, *kernel.backward(ctx, *grads_out).arrays().values()))
    for other in results[1:]:
        for a, b in zip(results[0], other, strict=True):
            np.testing.assert_array_equal(a, b)


def test_extreme_finite_inputs_give_finite_outputs():
    rng = np.random.default_rng(1)
    n = 300

    def wild(shape):
        return rng.choice([-1, 1], shape) * 10.0 ** rng.uniform(-30, 30, shape)

    means = np.where(rng.uniform(size=(n, 3)) < 0.5, wild((n, 3)), rng.normal(0, 0.5, (n, 3)))
    means[:, 2] = np.abs(means[:, 2])
    log_scales = np.where(rng.uniform(size=(n, 3)) < 0.3, wild((n, 3)), rng.normal(-2, 2, (n, 3)))
    g = SplatFrame(
        means=means,
        log_scales=log_scales,
        quats=wild((n, 4)),
        opacity_logits=wild(n),
        sh=wild((n, 3)) * 1e-3,
    ).checked()
    for antialiased in (False, True):
        raster, ctx = render(g, 16, 12, camera(16, 12), antialiased=antialiased)
        assert ctx.stats()["visible"] > 0
        grads = backward_ones(ctx).arrays().values()
        assert all(np.isfinite(x).all() for x in (*raster, *grads))
