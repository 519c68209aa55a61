"""What Blender shows of a trained avatar with spherical-harmonic colour (bpy 5.0.1): by default
the full colour towards the scene camera, as the exact splat render evaluates it; with
view-dependent colour off, the DC term, decoded without the higher bands. And culling to the
scene camera: fewer Gaussians decoded and drawn for a close camera, the same image."""

import importlib
import json
import subprocess
import sys

import bpy
import numpy as np
import pytest
from training_subject import TINY_CONFIG

from archhead_addon.splat.colour_space import linear_to_srgb
from archhead_addon.splat.sh import sh_to_rgb_numpy

pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def sh_avatar(tmp_path_factory, tiny_subject, demo_scene, repo_root):
    """A degree-3 avatar trained for TINY_CONFIG's 32 steps by the training command, loaded
    on the demo head."""
    folder = tmp_path_factory.mktemp("sh_avatar")
    config = folder / "config.json"
    config.write_text(
        json.dumps({**TINY_CONFIG, "avatar": {**TINY_CONFIG["avatar"], "sh_degree": 3}})
    )
    subprocess.run(
        [sys.executable, "-m", "archhead_addon.train", "--data", str(tiny_subject),
         "--out", str(folder / "run"), "--config", str(config)],
        check=True, capture_output=True, timeout=600, cwd=repo_root,
    )  # fmt: skip
    checkpoint = folder / "run" / "avatar.npz"
    head, _ = demo_scene(folder)
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.archhead.load_avatar(filepath=str(checkpoint)) == {"FINISHED"}
    obj = bpy.data.objects[f"{head.name}_avatar"]
    bpy.context.scene.frame_set(2)
    return {"obj": obj}


def _module(name):
    return importlib.import_module(f"archhead_blender.{name}")


def _levels(linear_rgb) -> np.ndarray:
    """8-bit display levels of linear colours (the Standard view transform's sRGB)."""
    return 255 * linear_to_srgb(linear_rgb[:, :3])


def test_the_default_display_shows_the_full_trained_colour(sh_avatar):
    obj = sh_avatar["obj"]
    assert obj.archhead_avatar.view_dependent  # the default
    scene, depsgraph = bpy.context.scene, bpy.context.evaluated_depsgraph_get()
    _, splat = _module("handlers").frame_to_show(obj, scene, depsgraph)
    assert splat.sh.shape[1] == 16 and np.abs(splat.sh[:, 1:]).max() > 0.02  # bands trained
    centre = _module("scene_state").camera_in_object(obj, scene, depsgraph)
    full = sh_to_rgb_numpy(3, splat.means - centre, splat.sh)  # linear: the avatar's space
    points = _module("point_instances").read_points(obj)
    shown = _levels(points["colour_view"])
    want = _levels(full)
    assert np.abs(shown - want).mean() < 1.0  # within one 8-bit level (the aim)
    # the DC term alone is visibly off: the check above could tell the two apart
    assert np.abs(_levels(points["colour"]) - want).mean() > 2 * np.abs(shown - want).mean()


def test_dc_display_decodes_and_caches_no_higher_bands(sh_avatar):
    obj = sh_avatar["obj"]
    obj.archhead_avatar.view_dependent = False
    try:
        scene, depsgraph = bpy.context.scene, bpy.context.evaluated_depsgraph_get()
        _, splat = _module("handlers").frame_to_show(obj, scene, depsgraph)
        assert splat.sh.shape[1:] == (1, 3)
        assert "colour_view" not in _module("point_instances").read_points(obj)
    finally:
        obj.archhead_avatar.view_dependent = True


def test_culling_to_a_close_camera_decodes_fewer_gaussians_for_the_same_image(sh_avatar):
    obj = sh_avatar["obj"]
    scene = bpy.context.scene
    camera = scene.camera
    saved = camera.matrix_world.copy()
    handlers, points = _module("handlers"), _module("point_instances")
    try:
        # move the camera towards the head until the frame holds about half of it
        head = obj.matrix_world.translation
        camera.location = head + (camera.location - head) * 0.25
        bpy.context.view_layer.update()
        depsgraph = bpy.context.evaluated_depsgraph_get()
        _, whole = handlers.frame_to_show(obj, scene, depsgraph)
        _, culled = handlers.frame_to_show(obj, scene, depsgraph, culled=True)
        assert len(culled) < 0.9 * len(whole)
        # the viewport keeps the whole avatar by default ("Renders"); "Always" culls there
        assert obj.archhead_avatar.cull == "RENDER"
        assert len(points.read_points(obj)["position"]) == len(whole)
        obj.archhead_avatar.cull = "ALWAYS"
        bpy.context.view_layer.update()
        assert len(points.read_points(obj)["position"]) == len(culled)
        # the same picture from that camera: the exact splat of both
        from archhead_addon.splat.blender_render import render_from_blender_camera

        cam = _module("scene_state").blender_camera(scene)
        args = (cam, np.array(camera.matrix_world), np.array(obj.matrix_world))
        a = render_from_blender_camera(whole, *args).rgb
        b = render_from_blender_camera(culled, *args).rgb
        assert a.max() > 0.1  # the avatar is in the picture
        assert 10 * np.log10(1.0 / max(np.mean((a - b) ** 2), 1e-20)) > 45.0
    finally:
        obj.archhead_avatar.cull = "RENDER"
        camera.matrix_world = saved
        bpy.context.view_layer.update()


def test_cycles_shows_what_the_exact_splat_render_shows(sh_avatar, tmp_path):
    """The trained avatar's point instances in Cycles against the kernel's image from the same
    camera: both blend its colours in linear light (splat/colour_space.py)."""
    scene = bpy.context.scene
    r = scene.render
    r.engine, r.film_transparent = "CYCLES", True
    scene.cycles.samples, scene.cycles.use_denoising = 32, False
    scene.cycles.use_adaptive_sampling = False
    r.resolution_x = r.resolution_y = 96
    r.resolution_percentage = 100
    r.threads_mode, r.threads = "FIXED", 2
    r.image_settings.file_format, r.image_settings.color_mode = "PNG", "RGBA"
    r.image_settings.color_depth = "8"
    scene.view_settings.view_transform = "Standard"
    batch = _module("batch_render")
    frame = scene.frame_current
    exact = batch.read_image(batch.render_frames(bpy.context, [frame], tmp_path, exact=True)[0])
    cycles = batch.read_image(batch.render_frames(bpy.context, [frame], tmp_path / "c")[0])

    def over_grey(rgba):
        return rgba[..., :3] * rgba[..., 3:] + 0.12 * (1 - rgba[..., 3:])

    assert exact[..., 3].max() > 0.9  # the avatar is in the picture
    mse = np.mean((over_grey(cycles) - over_grey(exact)) ** 2)
    psnr = 10 * np.log10(1.0 / mse)
    print(f"PSNR Cycles / exact splat, trained SH avatar: {psnr:.1f} dB")
    assert psnr > 36.0, psnr  # 41.4 dB measured; the aim is 32
