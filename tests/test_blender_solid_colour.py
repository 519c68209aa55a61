"""Solid mode (Workbench) colours each avatar by its own material's display colour, the mean
of its points' colours; the bpy module renders Workbench, which is what Solid mode draws.
(tests/ui/blender/solid_colour.py checks the real viewport.)"""

import subprocess
import sys

import bpy
import numpy as np
import pytest
from coloured_avatar import SKIN, write_coloured_avatar

from archhead_addon.avatar.point_attributes import srgb_to_linear

pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def coloured(tmp_path_factory, demo_scene, tiny_checkpoint):
    folder = tmp_path_factory.mktemp("solid")
    head, _ = demo_scene(folder)
    path = write_coloured_avatar(tiny_checkpoint, folder / "skin.npz")
    bpy.context.view_layer.objects.active = head
    assert bpy.ops.archhead.load_avatar(filepath=str(path)) == {"FINISHED"}
    return head, bpy.data.objects[f"{head.name}_avatar"], folder


def test_each_avatar_has_its_own_material_in_the_mean_colour(coloured):
    from archhead_blender.point_instances import MATERIAL, avatar_material

    _, obj, _ = coloured
    mat = avatar_material(obj)
    assert mat.name != MATERIAL and mat.users >= 1
    assert mat.node_tree is not bpy.data.materials[MATERIAL].node_tree  # a copy, same shader
    want = srgb_to_linear(np.array(SKIN))
    np.testing.assert_allclose(mat.diffuse_color[:3], want, atol=2e-3)
    np.testing.assert_allclose(obj.color[:3], want, atol=2e-3)


WORKBENCH_RENDER = """
import sys, bpy, numpy as np
bpy.ops.wm.open_mainfile(filepath=sys.argv[-2])
scene = bpy.context.scene
scene.render.engine = "BLENDER_WORKBENCH"
scene.display.shading.color_type = "MATERIAL"
scene.render.film_transparent = True
scene.render.resolution_x = scene.render.resolution_y = 64
scene.render.filepath = sys.argv[-1]
bpy.ops.render.render(write_still=True)
pixels = np.array(bpy.data.images.load(sys.argv[-1]).pixels[:]).reshape(-1, 4)
avatar = pixels[pixels[:, 3] > 0.9, :3]
print("AVATAR", len(avatar), *np.median(avatar, axis=0))
"""


def test_workbench_draws_the_avatar_in_its_colour(coloured):
    """Rendered with Workbench from the head's tracked camera: the avatar's pixels are the
    skin colour shaded by the studio light (no grey could keep r > g > b this far apart).
    In a process of its own: a GPU context in this one breaks later imports (triton's)."""
    head, obj, folder = coloured
    obj.archhead_avatar.lod = 1.0
    bpy.context.view_layer.update()
    bpy.context.scene.camera = bpy.data.objects[f"{head.name}_camera"]
    blend = folder / "solid.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)  # the points as they are
    result = subprocess.run(
        [sys.executable, "-c", WORKBENCH_RENDER, str(blend), str(folder / "solid.png")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    line = next((x for x in result.stdout.splitlines() if x.startswith("AVATAR")), None)
    assert line, result.stdout[-2000:] + result.stderr[-2000:]
    count, r, g, b = line.split()[1:]
    assert int(count) > 100
    r, g, b = float(r), float(g), float(b)
    assert r > g + 0.15 and g > b + 0.05, (r, g, b)


def test_a_group_from_before_the_material_input_is_upgraded(coloured):
    """A file saved before each avatar had its material: the group gains the input and the
    avatars there keep the shared Gaussian material."""
    from archhead_blender.compat import modifier_input, set_modifier_input
    from archhead_blender.point_instances import MATERIAL, MATERIAL_INPUT, gaussian_node_group

    _, obj, _ = coloured
    group = obj.modifiers[0].node_group
    socket = group.interface.items_tree[MATERIAL_INPUT]
    own = modifier_input(obj.modifiers[0], socket.identifier)
    group.interface.remove(socket)  # Blender drops the modifier's value with it
    bpy.context.view_layer.update()
    try:
        assert gaussian_node_group() is group
        socket = group.interface.items_tree[MATERIAL_INPUT]
        assert modifier_input(obj.modifiers[0], socket.identifier) == bpy.data.materials[MATERIAL]
        set_material = next(n for n in group.nodes if n.bl_idname == "GeometryNodeSetMaterial")
        assert set_material.inputs["Material"].is_linked
    finally:
        set_modifier_input(obj.modifiers[0], socket.identifier, own)
