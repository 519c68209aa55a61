"""The avatar in Blender (bpy 5.0.1): decoding the head's own codes into point instances, the
level of detail and its camera driver, decoded frame sets, handlers in a background render,
PLY export, the batch script through the bpy module, and EEVEE/Cycles against exact splats."""

import importlib
import subprocess
import sys

import bpy
import numpy as np
import pytest
from bpy_extras.anim_utils import action_get_channelbag_for_slot
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Matrix, Vector

from archhead_addon.avatar.gaussians import SH_C0
from archhead_addon.avatar.lod import resolution_for_lod
from archhead_addon.camera import FLAME_TO_BLENDER
from archhead_addon.export.ply import read_ply, rows_to_gaussians
from archhead_addon.splat.colour_space import linear_to_srgb
from archhead_addon.splat.frame import SplatFrame

pytestmark = pytest.mark.blender

SEQ_CODES = ("expr", "jaw", "neck", "eyes", "rotation", "translation")


@pytest.fixture(scope="module")
def scene_setup(tmp_path_factory, demo_scene, tiny_checkpoint):
    folder = tmp_path_factory.mktemp("avatar")
    head, seq = demo_scene(folder)
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.archhead.load_avatar(filepath=str(tiny_checkpoint)) == {"FINISHED"}
    obj = bpy.data.objects[f"{head.name}_avatar"]
    return {"head": head, "seq": seq, "obj": obj, "folder": folder}


@pytest.fixture
def avatar(scene_setup):
    """The avatar at LOD 0, decoding live, no LOD animation, at frame 1."""
    obj = scene_setup["obj"]
    obj.animation_data_clear()
    settings = obj.archhead_avatar
    settings.lod, settings.between, settings.view_dependent = 0.0, "LIVE", False
    bpy.context.scene.frame_set(1)
    return scene_setup


def _batch(setup):
    return importlib.import_module("archhead_blender.batch_render")


def _session(setup):
    return importlib.import_module("archhead_blender.avatar_session").session(setup["obj"])


def _points(setup):
    return importlib.import_module("archhead_blender.point_instances").read_points(setup["obj"])


def _expected(setup, frame: int, lod: float) -> SplatFrame:
    """Gaussians of the tracked codes themselves (what the import put on the head)."""
    seq, runtime = setup["seq"], _session(setup).runtime
    codes = {k: getattr(seq, k)[frame - 1] for k in SEQ_CODES}
    return SplatFrame.from_gaussians(runtime.decode(lod, **codes))


def _table_count(setup, lod: float) -> int:
    return _session(setup).runtime.raster.table(resolution_for_lod(lod)[1]).count


def test_points_are_the_decoded_codes_of_the_head(avatar):
    obj, head = avatar["obj"], avatar["head"]
    assert obj.parent == head.parent and obj.modifiers[0].node_group.name == "ArchHead Gaussians"
    np.testing.assert_allclose(np.array(obj.matrix_world), FLAME_TO_BLENDER, atol=1e-6)
    assert not head.visible_camera and head.display_type == "BOUNDS"
    assert head.show_only_shape_key and head.active_shape_key_index == 0  # keys still drive
    assert bpy.context.scene.render.use_lock_interface
    for frame in (1, 4):
        bpy.context.scene.frame_set(frame)
        points, want = _points(avatar), _expected(avatar, frame, 0.0)
        assert len(points["position"]) == len(want) == _table_count(avatar, 0.0)
        np.testing.assert_allclose(points["position"], want.means, atol=2e-5)
        np.testing.assert_allclose(points["rotation"], want.quats, atol=1e-4)
        np.testing.assert_allclose(np.log(points["scale"]), want.log_scales, atol=1e-4)
        assert points["rotation"].dtype == np.float32 and "colour_view" not in points
    attrs = obj.data.attributes
    assert attrs["rotation"].data_type == "QUATERNION" and attrs["colour"].domain == "POINT"


def test_shape_key_edit_drives_the_avatar(avatar):
    """An artist's edit of an expression shape key re-decodes: the points follow it."""
    head = avatar["head"]
    block = head.data.shape_keys.key_blocks["expr_000"]
    anim = head.data.shape_keys.animation_data
    curve = action_get_channelbag_for_slot(anim.action, anim.action_slot).fcurves.find(
        'key_blocks["expr_000"].value'
    )
    before = _points(avatar)["position"]
    curve.mute = True  # the key's animation off, a hand-set value on
    try:
        block.value = 2.5
        bpy.context.view_layer.update()
        after = _points(avatar)["position"]
        assert np.abs(after - before).max() > 1e-4
        codes = {k: getattr(avatar["seq"], k)[0].copy() for k in SEQ_CODES}
        codes["expr"][0] = 2.5
        want = SplatFrame.from_gaussians(_session(avatar).runtime.decode(0.0, **codes))
        np.testing.assert_allclose(after, want.means, atol=2e-5)
    finally:
        curve.mute = False
        bpy.context.scene.frame_set(1)


def test_lod_changes_follow_the_table(avatar):
    obj = avatar["obj"]
    settings = obj.archhead_avatar
    counts = []
    for lod in (0.0, 0.37, 1.0):
        settings.lod = lod
        bpy.context.view_layer.update()
        counts.append(len(obj.data.vertices))
        assert counts[-1] == _table_count(avatar, lod)
    assert counts[0] > counts[1] > counts[2]
    settings.lod = 1.0
    settings.keyframe_insert("lod", frame=1)
    settings.lod = 0.0
    settings.keyframe_insert("lod", frame=3)
    for frame in (1, 3, 2):
        bpy.context.scene.frame_set(frame)
        lod = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).archhead_avatar.lod
        assert len(obj.data.vertices) == _table_count(avatar, lod)
    assert 0.0 < lod < 1.0


def test_decode_frames_hold_and_disk_cache(avatar, tmp_path):
    obj = avatar["obj"]
    settings = obj.archhead_avatar
    settings.decode_frames, settings.stride = "STRIDE", 3
    settings.disk_cache, settings.cache_dir = True, str(tmp_path / "cache")
    try:
        assert bpy.ops.archhead.decode_avatar() == {"FINISHED"}
        decoded = _session(avatar).decoded
        assert sorted(decoded) == [1, 4]
        assert len(list((tmp_path / "cache").glob("*.npz"))) == 2
        settings.between = "HOLD"
        bpy.context.scene.frame_set(3)  # holds frame 1
        np.testing.assert_allclose(
            _points(avatar)["position"], _expected(avatar, 1, 0.0).means, atol=2e-5
        )
        settings.between = "LIVE"
        bpy.context.view_layer.update()
        np.testing.assert_allclose(
            _points(avatar)["position"], _expected(avatar, 3, 0.0).means, atol=2e-5
        )
        # a new session (a reopened file, another machine) reads frames from the disk cache
        importlib.import_module("archhead_blender.state").reset()
        bpy.context.scene.frame_set(4)
        runtime = _session(avatar).runtime
        assert runtime.level.misses == 0  # nothing was decoded
        np.testing.assert_allclose(
            _points(avatar)["position"], _expected(avatar, 4, 0.0).means, atol=2e-5
        )
    finally:
        settings.disk_cache, settings.between = False, "LIVE"


def test_lod_driver_by_camera_distance(avatar):
    obj, head = avatar["obj"], avatar["head"]
    camera = bpy.context.scene.camera
    camera.animation_data_clear()
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.archhead.drive_lod(near=0.5, far=1.5) == {"FINISHED"}
    driver = obj.animation_data.drivers.find("archhead_avatar.lod").driver
    assert driver.is_simple_expression and driver.is_valid
    rig = head.parent
    for distance, want in ((0.7, 0.2), (1.2, 0.7)):
        root = rig.matrix_world @ rig.pose.bones["global"].head
        camera.location = root + Vector((0.0, -distance, 0.0))
        bpy.context.view_layer.update()
        lod = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).archhead_avatar.lod
        assert lod == pytest.approx(want, abs=1e-5)
        assert len(obj.data.vertices) == _table_count(avatar, want)
    # another camera made active (by hand or a camera marker) drives it from then on
    other = bpy.data.objects.new("other_camera", bpy.data.cameras.new("other_camera"))
    bpy.context.scene.collection.objects.link(other)
    root = rig.matrix_world @ rig.pose.bones["global"].head
    other.location = root + Vector((0.0, -1.4, 0.0))
    bpy.context.scene.camera = other
    try:
        for _ in range(2):  # the handler retargets, the next evaluation reads the new camera
            bpy.context.view_layer.update()
        lod = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).archhead_avatar.lod
        assert lod == pytest.approx(0.9, abs=1e-5)
        assert driver.variables["d"].targets[0].id == other
    finally:
        bpy.context.scene.camera = camera
        bpy.data.objects.remove(other)
    obj.driver_remove("archhead_avatar.lod")


def test_handlers_in_a_background_render(avatar):
    """Cycles renders frames with the LOD keyed per frame: the handler rewrites the points
    inside the render (counts per frame) and the head moves with its root translation."""
    obj = avatar["obj"]
    scene = bpy.context.scene
    settings = obj.archhead_avatar
    for frame, lod in ((1, 1.0), (4, 0.5)):
        settings.lod = lod
        settings.keyframe_insert("lod", frame=frame)
    seen = {}

    def record(scene_, *_):
        seen[scene_.frame_current] = len(obj.data.vertices)

    _small_cycles(scene, samples=1)
    scene.render.film_transparent = True
    scene.render.image_settings.file_format = "OPEN_EXR"
    bpy.app.handlers.render_post.append(record)
    try:
        out = avatar["folder"] / "render"
        written = _batch(avatar).render_frames(bpy.context, [1, 4], out)
    finally:
        bpy.app.handlers.render_post.remove(record)
    assert seen == {1: _table_count(avatar, 1.0), 4: _table_count(avatar, 0.5)}
    centroids, projected = [], []
    for path, frame, lod in zip(written, (1, 4), (1.0, 0.5), strict=True):
        image = bpy.data.images.load(str(path))
        alpha = np.array(image.pixels[:]).reshape(image.size[1], image.size[0], 4)[..., 3]
        centroids.append((alpha.sum(0) * (np.arange(alpha.shape[1]) + 0.5)).sum() / alpha.sum())
        scene.frame_set(frame)
        centre = obj.matrix_world @ Vector(_expected(avatar, frame, lod).means.mean(0).tolist())
        projected.append(world_to_camera_view(scene, scene.camera, centre).x * alpha.shape[1])
    # each frame was rendered with its own points: the image moves as the decoded head does
    assert abs(projected[1] - projected[0]) > 2.0
    assert centroids[1] - centroids[0] == pytest.approx(projected[1] - projected[0], rel=0.25)


def test_ply_export_round_trip(avatar, tmp_path):
    obj = avatar["obj"]
    bpy.context.view_layer.objects.active = obj
    path = tmp_path / "frame.ply"
    assert bpy.ops.archhead.export_ply(filepath=str(path)) == {"FINISHED"}
    want = _expected(avatar, 1, 0.0)
    got = rows_to_gaussians(read_ply(path))
    for name in ("means", "log_scales", "quats", "opacity_logits"):
        np.testing.assert_allclose(got[name], getattr(want, name), atol=2e-5)
    # the avatar blends linear colours; the file holds display colours, as 3DGS readers blend
    linear = np.maximum(0.5 + SH_C0 * want.sh[:, 0], 0)
    np.testing.assert_allclose(0.5 + SH_C0 * got["sh"][:, 0], linear_to_srgb(linear), atol=2e-5)
    assert bpy.ops.archhead.export_ply(
        filepath=str(tmp_path / "w_##.ply"), frames="CUSTOM", custom_frames="2-3", space="WORLD"
    ) == {"FINISHED"}
    world = rows_to_gaussians(read_ply(tmp_path / "w_02.ply"))
    flame = _expected(avatar, 2, 0.0).means
    np.testing.assert_allclose(world["means"], flame @ FLAME_TO_BLENDER[:3, :3].T, atol=2e-5)
    assert (tmp_path / "w_03.ply").is_file()
    # Blender's own importer reads every field
    assert bpy.ops.wm.ply_import(filepath=str(path)) == {"FINISHED"}
    imported = bpy.context.selected_objects[0]
    assert len(imported.data.vertices) == len(want)
    names = set(imported.data.attributes.keys())
    assert {"f_dc_0", "f_dc_2", "opacity", "scale_2", "rot_3"} <= names
    values = np.empty(len(want), np.float32)
    imported.data.attributes["rot_0"].data.foreach_get("value", values)
    np.testing.assert_allclose(values, want.quats[:, 0], atol=1e-6)
    bpy.data.meshes.remove(imported.data)


def test_batch_script_exact_splat_through_the_bpy_module(avatar, tmp_path, repo_root):
    """`python scripts/batch_render.py scene.blend --exact ...` renders with the kernel;
    its image matches Cycles' render of the point instances."""
    scene = bpy.context.scene
    avatar["obj"].archhead_avatar.view_dependent = True  # the splat evaluates the full SH
    _small_cycles(scene, samples=32)
    scene.render.film_transparent = True
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.image_settings.color_depth = "8"  # 16-bit PNGs load linearised
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    out = tmp_path / "exact"
    result = subprocess.run(
        [
            sys.executable,
            str(repo_root / "scripts/batch_render.py"),
            str(blend),
            "--frames",
            "2",
            "--lod",
            "0.5",
            "--exact",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    read_image = _batch(avatar).read_image
    exact = read_image(out / "frame_0002.png")
    assert exact[..., 3].max() > 0.99 and exact[..., 3].min() == 0.0
    cycles_files = _batch(avatar).render_frames(bpy.context, [2], tmp_path / "cycles", lod=0.5)
    cycles = read_image(cycles_files[0])
    psnr = 10 * np.log10(1.0 / np.mean((_over_black(cycles) - _over_black(exact)) ** 2))
    print(f"PSNR Cycles / exact splat: {psnr:.1f} dB")
    assert psnr > 24.0, psnr


def _small_cycles(scene, samples):
    scene.render.engine = "CYCLES"
    scene.cycles.samples, scene.cycles.use_denoising = samples, False
    scene.cycles.use_adaptive_sampling = False
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.resolution_percentage = 100
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    scene.view_settings.view_transform = "Standard"


def _over_black(rgba):
    return rgba[..., :3] * rgba[..., 3:]


def test_avatar_load_refuses_a_mismatched_checkpoint(avatar, tmp_path, tiny_checkpoint):
    from archhead_addon.avatar.checkpoint_format import read_checkpoint, write_checkpoint

    ckpt = read_checkpoint(tiny_checkpoint)
    ckpt.model_id = "flame2023"
    wrong = tmp_path / "other_model.npz"
    write_checkpoint(wrong, ckpt)
    bpy.context.view_layer.objects.active = avatar["head"]
    with pytest.raises(RuntimeError, match="trained on the model 'flame2023'"):
        bpy.ops.archhead.load_avatar(filepath=str(wrong))
    assert avatar["obj"].archhead_avatar.checkpoint.endswith("tiny_avatar.npz")


def test_matrix_world_follows_the_rig(avatar):
    """Moving the rig object moves the instances with it (they live in FLAME space)."""
    rig = avatar["head"].parent
    saved = rig.matrix_world.copy()
    rig.matrix_world = Matrix.Translation((1.0, 2.0, 3.0)) @ saved
    bpy.context.view_layer.update()
    np.testing.assert_allclose(np.array(avatar["obj"].matrix_world)[:3, 3], [1, 2, 3], atol=1e-6)
    rig.matrix_world = saved


def test_export_without_an_avatar_says_what_to_select(avatar, tmp_path):
    """File > Export > Gaussians is greyed out with no avatar active; its tooltip (the poll
    message, which bpy.ops also raises) says what to select."""
    other = bpy.data.objects.new("not_a_head", None)
    bpy.context.scene.collection.objects.link(other)
    bpy.context.view_layer.objects.active = other
    try:
        with pytest.raises(RuntimeError, match="Select an ArchHead avatar"):
            bpy.ops.archhead.export_ply(filepath=str(tmp_path / "none.ply"))
    finally:
        bpy.context.view_layer.objects.active = avatar["obj"]
        bpy.data.objects.remove(other)
