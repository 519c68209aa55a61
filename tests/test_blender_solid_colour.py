"""Solid mode (Workbench) colours each avatar by its own material's display colour, the mean
of its points' colours; the bpy module renders Workbench, which is what Solid mode draws.
(tests/ui/blender/solid_colour.py checks the real viewport.)"""

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


def test_workbench_draws_the_avatar_in_its_colour(coloured):
    """Rendered with Workbench from the head's tracked camera: the avatar's pixels are the
    skin colour shaded by the studio light (no grey could keep r > g > b this far apart)."""
    head, obj, folder = coloured
    scene = bpy.context.scene
    obj.archhead_avatar.lod = 1.0
    scene.camera = bpy.data.objects[f"{head.name}_camera"]
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.color_type = "MATERIAL"
    scene.render.film_transparent = True
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.filepath = str(folder / "solid.png")
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(scene.render.filepath)
    pixels = np.array(image.pixels[:]).reshape(-1, 4)
    avatar = pixels[pixels[:, 3] > 0.9, :3]
    assert len(avatar) > 100
    r, g, b = np.median(avatar, axis=0)
    assert r > g + 0.15 and g > b + 0.05, (r, g, b)


def test_a_group_from_before_the_material_input_is_upgraded(coloured):
    """A file saved before each avatar had its material: the group gains the input and the
    avatars there keep the shared Gaussian material."""
    from archhead_blender.point_instances import MATERIAL, MATERIAL_INPUT, gaussian_node_group

    _, obj, _ = coloured
    group = obj.modifiers[0].node_group
    socket = group.interface.items_tree[MATERIAL_INPUT]
    own = obj.modifiers[0][socket.identifier]
    group.interface.remove(socket)  # Blender drops the modifier's value with it
    bpy.context.view_layer.update()
    try:
        assert gaussian_node_group() is group
        socket = group.interface.items_tree[MATERIAL_INPUT]
        assert obj.modifiers[0][socket.identifier] == bpy.data.materials[MATERIAL]
        set_material = next(n for n in group.nodes if n.bl_idname == "GeometryNodeSetMaterial")
        assert set_material.inputs["Material"].is_linked
    finally:
        obj.modifiers[0][socket.identifier] = own
