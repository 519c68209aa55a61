"""Exact splat renders from a Blender camera: the OpenCV camera derived from Blender's
numbers projects like Blender itself (bpy's world_to_camera_view), and a rendered Gaussian
lands where Blender projects its centre."""

import bpy
import numpy as np
import pytest
import torch
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Matrix, Vector

from archhead_addon.camera import FLAME_TO_BLENDER, BlenderCamera
from archhead_addon.splat import rasterize_frame
from archhead_addon.splat.blender_render import (
    blender_camera_to_opencv,
    render_from_blender_camera,
)
from archhead_addon.splat.frame import SplatFrame

pytestmark = pytest.mark.blender

CAMERAS = [
    BlenderCamera(
        lens=50.0, sensor_width=36.0, shift_x=0.0, shift_y=0.0, resolution_x=64, resolution_y=48
    ),
    BlenderCamera(
        lens=35.0,
        sensor_width=32.0,
        shift_x=0.12,
        shift_y=-0.07,
        resolution_x=40,
        resolution_y=56,
        pixel_aspect_x=1.0,
        pixel_aspect_y=1.25,
    ),
    BlenderCamera(
        lens=40.0,
        sensor_width=30.0,
        shift_x=-0.05,
        shift_y=0.1,
        resolution_x=36,
        resolution_y=60,
        sensor_fit="AUTO",
    ),  # portrait: AUTO fits the height
    BlenderCamera(
        lens=28.0,
        sensor_width=36.0,
        sensor_height=20.0,
        shift_x=0.03,
        shift_y=-0.02,
        resolution_x=64,
        resolution_y=40,
        pixel_aspect_x=1.5,
        sensor_fit="VERTICAL",
    ),
]
CAMERA_IDS = ["default", "shift_aspect", "auto_portrait", "vertical_aspect"]


def bpy_camera(cam: BlenderCamera, matrix_world):
    scene = bpy.context.scene
    data = bpy.data.cameras.new("splat_test_camera")
    data.sensor_fit = cam.sensor_fit
    data.lens, data.sensor_width, data.sensor_height = (
        cam.lens,
        cam.sensor_width,
        (cam.sensor_height),
    )
    data.shift_x, data.shift_y = cam.shift_x, cam.shift_y
    obj = bpy.data.objects.new("splat_test_camera", data)
    scene.collection.objects.link(obj)
    obj.matrix_world = Matrix(matrix_world.tolist())
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = (
        cam.resolution_x,
        cam.resolution_y,
        100,
    )
    r.pixel_aspect_x, r.pixel_aspect_y = cam.pixel_aspect_x, cam.pixel_aspect_y
    return scene, obj


def bpy_pixels(scene, obj, cam, points_blender):
    """Pixel coordinates (x right, y down, origin at the top-left corner) from Blender."""
    out = []
    for p in points_blender:
        ndc = world_to_camera_view(scene, obj, Vector(p.tolist()))
        out.append((ndc.x * cam.resolution_x, (1 - ndc.y) * cam.resolution_y))
    return np.array(out)


def look_from(eye, target):
    """Blender camera matrix_world at eye looking at target (camera -Z forward, +Y up)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, :3] = np.stack([right, np.cross(back, right), back], -1)
    m[:3, 3] = eye
    return m


@pytest.fixture(autouse=True)
def restore_blender_state():
    """Leave the session's Blender data as found (other test modules share it)."""
    r = bpy.context.scene.render
    keys = (
        "resolution_x",
        "resolution_y",
        "resolution_percentage",
        "pixel_aspect_x",
        "pixel_aspect_y",
    )
    saved = {k: getattr(r, k) for k in keys}
    yield
    for k, v in saved.items():
        setattr(r, k, v)
    for obj in [o for o in bpy.data.objects if o.name.startswith("splat_test_camera")]:
        bpy.data.objects.remove(obj)
    for data in [c for c in bpy.data.cameras if c.name.startswith("splat_test_camera")]:
        bpy.data.cameras.remove(data)


@pytest.mark.parametrize("cam", CAMERAS, ids=CAMERA_IDS)
def test_opencv_camera_projects_like_blender(cam):
    rng = np.random.default_rng(0)
    matrix_world = look_from((0.3, -0.7, 0.2), (0.0, 0.0, 0.05))
    scene, obj = bpy_camera(cam, matrix_world)
    points = rng.normal(0, 0.08, (20, 3))  # Blender world, around the head
    viewmat, K = blender_camera_to_opencv(cam, matrix_world, np.eye(4))
    cam_pts = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    ours = (cam_pts @ K.T)[:, :2] / cam_pts[:, 2:]
    np.testing.assert_allclose(ours, bpy_pixels(scene, obj, cam, points), atol=1e-3)


@pytest.mark.parametrize("cam", CAMERAS, ids=CAMERA_IDS)
def test_rendered_gaussian_lands_where_blender_projects_it(cam):
    """A small round Gaussian in FLAME space: its alpha-weighted centroid in the exact render
    equals Blender's projection of FLAME_TO_BLENDER @ mean (pixel centres at +0.5)."""
    matrix_world = look_from((0.1, -0.6, 0.15), (0.0, 0.0, 0.0))
    scene, obj = bpy_camera(cam, matrix_world)
    mean_flame = np.array([0.012, 0.02, 0.01])
    viewmat, K = blender_camera_to_opencv(cam, matrix_world)
    depth = (viewmat[:3, :3] @ mean_flame + viewmat[:3, 3])[2]
    sigma = 2.0 * depth / K[0, 0]  # about 2 px
    frame = SplatFrame(
        means=mean_flame[None],
        log_scales=np.full((1, 3), np.log(sigma)),
        quats=np.array([[1.0, 0, 0, 0]]),
        opacity_logits=np.array([3.0]),
        sh=np.array([[1.0, 1.0, 1.0]]),
    )
    raster = render_from_blender_camera(frame, cam, matrix_world)
    ys, xs = np.mgrid[: cam.resolution_y, : cam.resolution_x] + 0.5
    w = raster.alpha
    centroid = np.array([(w * xs).sum() / w.sum(), (w * ys).sum() / w.sum()])
    mean_blender = (FLAME_TO_BLENDER @ np.append(mean_flame, 1.0))[:3]
    expected = bpy_pixels(scene, obj, cam, mean_blender[None])[0]
    assert raster.alpha.max() > 0.5
    np.testing.assert_allclose(centroid, expected, atol=0.01)  # a half-pixel slip fails
    assert raster.depth[raster.alpha > 0.5] == pytest.approx(depth, rel=1e-5)


def test_blender_render_with_sh_matches_rasterization():
    rng = np.random.default_rng(3)
    cam = CAMERAS[1]
    matrix_world = look_from((0.0, -0.6, 0.0), (0.0, 0.0, 0.0))
    n = 300
    means = rng.normal(0, 0.06, (n, 3))
    quats = rng.normal(size=(n, 4))
    log_scales = rng.normal(np.log(0.01), 0.3, (n, 3))
    logits = rng.normal(1, 1, n)
    sh = rng.normal(0, 0.3, (n, 16, 3))
    frame = SplatFrame(
        means=means, log_scales=log_scales, quats=quats, opacity_logits=logits, sh=sh
    )
    ours = render_from_blender_camera(frame, cam, matrix_world, background=(0.1, 0.1, 0.1))
    viewmat, K = blender_camera_to_opencv(cam, matrix_world)
    ref = rasterize_frame(
        frame.map(lambda a: torch.tensor(a, dtype=torch.float32)),
        viewmat,
        K,
        cam.resolution_x,
        cam.resolution_y,
        background=(0.1, 0.1, 0.1),
    )
    assert ours.alpha.max() > 0.9
    np.testing.assert_allclose(ours.rgb, ref.rgb.numpy(), atol=1e-5)
    np.testing.assert_allclose(ours.alpha, ref.alpha[..., 0].numpy(), atol=1e-6)


def test_object_transform_folds_into_the_view():
    """Gaussians in a rotated, uniformly scaled, moved object render like the same Gaussians
    moved into the world by hand."""
    from archhead_addon.rotations import (
        axis_angle_to_matrix,
        matrix_to_quaternion,
        quaternion_to_matrix,
    )

    rng = np.random.default_rng(5)
    cam = CAMERAS[0]
    camera_matrix_world = look_from((0.2, -0.8, 0.3), (0.0, 0.0, 0.1))
    n = 200
    means = rng.normal(0, 0.05, (n, 3))
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    log_scales = rng.normal(np.log(0.008), 0.3, (n, 3))
    logits, colors = rng.normal(1, 1, n), rng.uniform(0, 1, (n, 3))
    R, scale = axis_angle_to_matrix(np.array([0.3, -0.5, 0.9])), 1.7
    obj = np.eye(4)
    obj[:3, :3], obj[:3, 3] = scale * R, (0.02, -0.03, 0.1)

    local = SplatFrame(
        means=means, log_scales=log_scales, quats=quats, opacity_logits=logits, sh=colors
    )
    moved = SplatFrame(
        means=means @ obj[:3, :3].T + obj[:3, 3],
        log_scales=log_scales + np.log(scale),
        quats=matrix_to_quaternion(R @ quaternion_to_matrix(quats)),
        opacity_logits=logits,
        sh=colors,
    )
    ours = render_from_blender_camera(local, cam, camera_matrix_world, obj)
    world = render_from_blender_camera(moved, cam, camera_matrix_world, np.eye(4))
    assert ours.alpha.max() > 0.9
    np.testing.assert_allclose(ours.rgb, world.rgb, atol=1e-5)
    np.testing.assert_allclose(ours.alpha, world.alpha, atol=1e-5)
    mask = ours.alpha > 0.5  # depth: camera z, in Blender world units either way
    np.testing.assert_allclose(ours.depth[mask], world.depth[mask], rtol=1e-5)
