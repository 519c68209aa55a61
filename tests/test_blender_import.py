"""Import exactness: Blender's evaluated mesh equals the FLAME forward pass; the imported
camera projects like K, R, t; the script path saves a .blend; failures leave nothing."""

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
from bpy_extras.object_utils import world_to_camera_view
from mathutils import Vector

from archhead_addon.camera import FLAME_TO_BLENDER, project
from archhead_addon.flame import load_model
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.teeth import add_teeth
from archhead_addon.sequences.canonical import write_canonical
from archhead_addon.sequences.demo import demo_sequence
from archhead_addon.sequences.sequence import Sequence

pytestmark = pytest.mark.blender

WIDTH, HEIGHT = 640, 480


def _extreme_sequence(model, n_frames=7, seed=0):
    rng = np.random.default_rng(seed)
    t = n_frames
    expr = rng.normal(size=(t, model.n_expr))
    expr[1] = 3.0
    expr[2] = -3.0
    jaw, neck, eyes, rot = (np.zeros((t, k)) for k in (3, 3, 6, 3))
    jaw[3] = [0.6, 0.05, -0.05]  # wide open
    neck[4] = [0.7, -1.2, 0.4]
    eyes[5] = [0.5, -0.6, 0.0, -0.5, 0.6, 0.1]
    rot[6] = [np.pi * 0.9, 0.1, 0.2]
    rot[1:3] = rng.normal(scale=0.3, size=(2, 3))
    K = np.array([[900.0, 0, 300.0], [0, 950.0, 260.0], [0, 0, 1]])
    w2c = np.tile(np.eye(4), (t, 1, 1))
    w2c[:, 2, 3] = 0.8 + 0.05 * np.arange(t)
    w2c[:, 0, 3] = 0.01 * np.arange(t)
    return Sequence(
        shape=np.tile(rng.normal(size=model.n_shape), (t, 1)),
        expr=expr,
        jaw=jaw,
        neck=neck,
        eyes=eyes,
        rotation=rot,
        translation=rng.normal(scale=0.02, size=(t, 3)),
        fps=30.0,
        frame_ids=np.arange(t),
        source="test",
        format="canonical",
        K=np.tile(K, (t, 1, 1)),
        w2c=w2c,
        image_size=(HEIGHT, WIDTH),
    )


@pytest.fixture(scope="module")
def imported(tmp_path_factory, addon):
    bpy.ops.wm.read_homefile(use_empty=True)
    model = add_teeth(load_model())
    seq = _extreme_sequence(model)
    path = tmp_path_factory.mktemp("seq") / "extreme.npz"
    write_canonical(seq, path)
    assert bpy.ops.archhead.import_sequence(filepath=str(path)) == {"FINISHED"}
    head = bpy.data.objects["extreme"]
    return addon, model, seq, head


def _evaluated_vertices(head, frame):
    bpy.context.scene.frame_set(frame)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = head.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    co = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", co)
    evaluated.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64)


def test_evaluated_mesh_equals_flame_forward(imported):
    _, model, seq, head = imported
    assert len(head.data.vertices) == model.n_verts
    worst = 0.0
    for i in range(len(seq)):
        codes = {
            k: getattr(seq, k)[i]
            for k in ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")
        }
        want = forward(model, **codes)[0]
        got = _evaluated_vertices(head, i + 1)
        worst = max(worst, np.abs(got - want).max())
    print(f"max vertex error over {len(seq)} frames: {worst:.2e} m")
    assert worst <= 1e-5


def test_camera_projects_like_k_r_t(imported):
    _, model, seq, head = imported
    scene = bpy.context.scene
    cam = scene.camera
    assert (scene.render.resolution_x, scene.render.resolution_y) == (WIDTH, HEIGHT)
    for i in (0, 3, 6):
        verts = forward(
            model,
            **{
                k: getattr(seq, k)[i]
                for k in ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")
            },
        )[0][::50]
        scene.frame_set(i + 1)
        want = project(verts, seq.K[i], seq.w2c[i])
        world = verts @ FLAME_TO_BLENDER[:3, :3].T
        ndc = np.array([world_to_camera_view(scene, cam, Vector(p))[:2] for p in world])
        got = np.stack([ndc[:, 0] * WIDTH, (1 - ndc[:, 1]) * HEIGHT], 1)
        assert np.abs(got - want).max() <= 0.5, i


def test_scene_settings_and_codes_on_object(imported):
    _, model, seq, head = imported
    scene = bpy.context.scene
    assert (scene.frame_start, scene.frame_end) == (1, len(seq))
    assert scene.render.fps == 30
    np.testing.assert_allclose(head["archhead_identity"], seq.shape[0], rtol=1e-6, atol=1e-6)
    assert head["archhead_model_id"] == model.model_id
    keys = head.data.shape_keys.key_blocks
    assert len(keys) == 1 + model.n_expr + 36
    assert keys["pose_jaw_00"].id_data.animation_data.drivers  # correctives are driven


def test_failed_import_leaves_nothing(tmp_path, imported):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an npz at all")
    before = {c: len(getattr(bpy.data, c)) for c in ("objects", "meshes", "actions")}
    with pytest.raises(RuntimeError, match=r"bad\.npz"):
        bpy.ops.archhead.import_sequence(filepath=str(bad))
    assert {c: len(getattr(bpy.data, c)) for c in before} == before


def test_script_imports_and_saves_blend(tmp_path, repo_root):
    """... and leaves no temporary folder behind (the checkout's extension repository is a
    folder holding a link to the checkout: removed, the checkout kept)."""
    seq_path = tmp_path / "clip.npz"
    write_canonical(demo_sequence(frames=8), seq_path)
    out = tmp_path / "clip.blend"
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    proc = subprocess.run(
        [
            sys.executable,
            str(repo_root / "scripts/import_sequence.py"),
            str(seq_path),
            str(out),
            "--stride",
            "2",
            "--expressions",
            "20",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "TMPDIR": str(scratch)},
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert out.stat().st_size > 100_000
    assert not list(scratch.iterdir())
    assert (repo_root / "blender_manifest.toml").is_file()
    bpy.ops.wm.open_mainfile(filepath=str(out))
    head = bpy.data.objects["clip"]
    assert (bpy.context.scene.frame_start, bpy.context.scene.frame_end) == (1, 7)  # 8 / stride 2
    assert head.data.shape_keys.key_blocks["expr_019"] and "expr_020" not in (
        head.data.shape_keys.key_blocks
    )


def test_keyframed_correctives_equally_exact(imported, tmp_path):
    _, model, seq, _ = imported
    path = tmp_path / "keyed.npz"
    write_canonical(seq, path)
    assert bpy.ops.archhead.import_sequence(
        filepath=str(path), pose_correctives="KEYFRAMES", use_camera=False
    ) == {"FINISHED"}
    head = bpy.data.objects["keyed"]
    assert not head.data.shape_keys.animation_data.drivers
    for i in (3, 4, 6):  # jaw, neck, near-pi global rotation
        codes = {
            k: getattr(seq, k)[i]
            for k in ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")
        }
        assert np.abs(_evaluated_vertices(head, i + 1) - forward(model, **codes)[0]).max() <= 1e-5


def test_expression_components_never_used_get_no_shape_key(imported, tmp_path):
    """Unused components in the middle of the range are left out too; the mesh stays exact."""
    _, model, seq, _ = imported
    expr = seq.expr.copy()
    expr[:, [0, 5, 6, 40]] = 0.0
    expr[:, 60:] = 0.0
    sparse = Sequence(**{**seq.__dict__, "expr": expr})
    path = tmp_path / "sparse.npz"
    write_canonical(sparse, path)
    assert bpy.ops.archhead.import_sequence(filepath=str(path), use_camera=False) == {"FINISHED"}
    head = bpy.data.objects["sparse"]
    names = {k.name for k in head.data.shape_keys.key_blocks if k.name.startswith("expr_")}
    assert names == {f"expr_{i:03d}" for i in range(60) if i not in (0, 5, 6, 40)}
    for i in (0, 1):
        codes = {
            k: getattr(sparse, k)[i]
            for k in ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")
        }
        got = _evaluated_vertices(head, i + 1)
        assert np.abs(got - forward(model, **codes)[0]).max() <= 1e-5


def test_heads_of_one_model_share_their_skin(imported, tmp_path):
    """A crowd of heads of one model packs its albedo once (it had cost 5 MB a head); a
    model with another albedo gets a material of its own."""
    _, model, seq, _ = imported
    heads = []
    for name in ("first", "second"):
        write_canonical(seq, tmp_path / f"{name}.npz")
        images = len(bpy.data.images)
        op = bpy.ops.archhead.import_sequence
        assert op(filepath=str(tmp_path / f"{name}.npz"), use_camera=False) == {"FINISHED"}
        heads.append(bpy.data.objects[name])
    assert len(bpy.data.images) == images  # the second head packed none
    head, second = heads
    assert second.data.materials[0] == head.data.materials[0]
    from archhead_blender.head_builder import _albedo_material, _Created

    other = _albedo_material(255 - model.albedo, "other", _Created())
    assert other != head.data.materials[0]
    assert other.node_tree.nodes["Image Texture"].image.size[:] == model.albedo.shape[1::-1]
