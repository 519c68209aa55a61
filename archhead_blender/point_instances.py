"""The avatar as point instances: a mesh of loose vertices carrying the Gaussians' attributes,
one Geometry Nodes group that puts an ellipsoid on every point, one emissive material with a
Gaussian falloff. Works the same in EEVEE and Cycles, in the viewport and in renders.

Points are loose mesh vertices (`vertices.add` + `foreach_set`), instanced directly by
"Instance on Points": `bpy.data.pointclouds` has no Python API to add points, and a mesh works
from Blender 4.2 to 5.x. The `rotation` attribute is of type QUATERNION, which the Named
Attribute node reads as a rotation socket, so it feeds "Instance on Points" as it is.

Each instance is a unit icosphere scaled to SIGMA_EXTENT standard deviations. The material
computes, in the instance's own space (where the Gaussian is isotropic), the squared distance
d^2 of the camera ray from the centre, in units of the sphere's radius, and gives the front face
alpha = opacity * exp(-d^2 SIGMA_EXTENT^2 / 2): the Gaussian's peak density along the ray, as a
splat renderer evaluates it. Back faces are fully transparent. Colours are emitted unlit.

Solid mode (Workbench) shows neither shader nodes nor instance attributes: it colours each
instance by its material's viewport display colour. So every avatar gets its own copy of the
material (a Material input of the node group, set on its modifier) whose display colour is
the avatar's mean colour (`show_mean_colour`), and the object's colour is the same, for
"Object" colouring.
"""

from __future__ import annotations

import bpy
import numpy as np

from .compat import ensure_node_tree, modifier_input, set_modifier_input

SIGMA_EXTENT = 3.0  # instance radius in standard deviations (3DGS' own 3-sigma extent)
ICO_SUBDIVISIONS = 2  # 80 faces: the falloff, not the facets, shapes each Gaussian
NODE_GROUP = "ArchHead Gaussians"
MATERIAL = "ArchHead Gaussian"
MATERIAL_INPUT = "Material"  # the node group's input: each avatar's own copy of MATERIAL
# attribute name -> (type, foreach_set field, components)
ATTRIBUTES = {
    "scale": ("FLOAT_VECTOR", "vector", 3),
    "rotation": ("QUATERNION", "value", 4),
    "opacity": ("FLOAT", "value", 1),
    "colour": ("FLOAT_COLOR", "color", 4),
    "colour_view": ("FLOAT_COLOR", "color", 4),
}


def create_point_object(name: str, parent, collection):
    """An empty point object under `parent` (the head's rig: FLAME space inside it)."""
    mesh = bpy.data.meshes.new(name)
    obj = bpy.data.objects.new(name, mesh)
    collection.objects.link(obj)
    obj.parent = parent
    obj.matrix_parent_inverse.identity()
    modifier = obj.modifiers.new("ArchHead Gaussians", "NODES")
    modifier.node_group = gaussian_node_group()
    obj.visible_shadow = False  # emitters of their own colour: they cast no shadow
    avatar_material(obj)
    return obj


def _gaussians_modifier(obj):
    return next(
        (m for m in obj.modifiers if m.type == "NODES" and m.node_group is gaussian_node_group()),
        None,
    )


def avatar_material(obj):
    """The avatar's own copy of the Gaussian material (made on first use; older files' avatars
    have none and show the shared one)."""
    modifier = _gaussians_modifier(obj)
    if modifier is None:
        return None
    key = _material_input(modifier.node_group).identifier
    mat = modifier_input(modifier, key)
    if mat is None or mat.name == MATERIAL:
        mat = gaussian_material().copy()
        mat.name = f"{obj.name} Gaussian"
        set_modifier_input(modifier, key, mat)
        obj.update_tag()
    return mat


def show_mean_colour(obj) -> tuple[float, float, float] | None:
    """Solid mode's colour of the avatar (its material's and its object's display colour):
    the opacity-weighted mean of its points' colours (scene-linear, as the attribute)."""
    mesh = obj.data
    n = len(mesh.vertices)
    if n == 0 or "colour" not in mesh.attributes:
        return None
    colour = _get(mesh.attributes["colour"], "color", n, 4)[:, :3]
    weight = _get(mesh.attributes["opacity"], "value", n, 1) + 1e-6
    rgb = tuple(float(c) for c in (colour * weight[:, None]).sum(0) / weight.sum())
    mat = avatar_material(obj)
    if mat is not None:
        mat.diffuse_color = (*rgb, 1.0)
    obj.color = (*rgb, 1.0)
    return rgb


def write_points(obj, attributes: dict[str, np.ndarray]) -> None:
    """Replace the point data with `point_attributes` arrays (bulk writes only). A point mesh
    that other objects use too (a linked duplicate, Alt+D) is copied first: each avatar
    shows its own head's frame."""
    if obj.data.users > 1:
        obj.data = obj.data.copy()
    mesh = obj.data
    # Fresh arrays every time: the evaluated scene still shares the last frame's, and writing
    # into a shared array makes Blender copy it first (20 % of a cached frame's write).
    mesh.clear_geometry()
    mesh.vertices.add(len(attributes["position"]))
    mesh.attributes["position"].data.foreach_set("vector", _flat(attributes["position"]))
    for name, (kind, field, _) in ATTRIBUTES.items():
        if name in attributes:
            mesh.attributes.new(name, kind, "POINT").data.foreach_set(
                field, _flat(attributes[name])
            )
    mesh.update()


def read_points(obj) -> dict[str, np.ndarray]:
    """The point data back (for tests and the exact splat path)."""
    mesh = obj.data
    n = len(mesh.vertices)
    out = {"position": _get(mesh.attributes["position"], "vector", n, 3)}
    for name, (_, field, width) in ATTRIBUTES.items():
        if name in mesh.attributes:
            out[name] = _get(mesh.attributes[name], field, n, width)
    return out


def _flat(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float32).ravel()


def _get(attr, field: str, n: int, width: int) -> np.ndarray:
    out = np.empty(n * width, np.float32)
    attr.data.foreach_get(field, out)
    return out.reshape(n, width) if width > 1 else out


def gaussian_node_group():
    """Instance on Points: icosphere x (scale * SIGMA_EXTENT), rotated by the quaternion."""
    group = bpy.data.node_groups.get(NODE_GROUP)
    if group is not None:
        _material_input(group)
        return group
    group = bpy.data.node_groups.new(NODE_GROUP, "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = group.nodes, group.links
    inp, out = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    sphere = nodes.new("GeometryNodeMeshIcoSphere")
    sphere.inputs["Radius"].default_value = 1.0
    sphere.inputs["Subdivisions"].default_value = ICO_SUBDIVISIONS
    set_material = nodes.new("GeometryNodeSetMaterial")
    set_material.inputs["Material"].default_value = gaussian_material()
    rotation = _named_attribute(nodes, "rotation", "QUATERNION")
    scale = _named_attribute(nodes, "scale", "FLOAT_VECTOR")
    extent = nodes.new("ShaderNodeVectorMath")
    extent.operation = "SCALE"
    extent.inputs["Scale"].default_value = SIGMA_EXTENT
    instance = nodes.new("GeometryNodeInstanceOnPoints")
    links.new(sphere.outputs["Mesh"], set_material.inputs["Geometry"])
    links.new(inp.outputs["Geometry"], instance.inputs["Points"])
    links.new(set_material.outputs["Geometry"], instance.inputs["Instance"])
    links.new(rotation.outputs["Attribute"], instance.inputs["Rotation"])
    links.new(scale.outputs["Attribute"], extent.inputs[0])
    links.new(extent.outputs["Vector"], instance.inputs["Scale"])
    links.new(instance.outputs["Instances"], out.inputs["Geometry"])
    _arrange([inp, sphere, set_material, rotation, scale, extent, instance, out])
    _material_input(group)
    return group


def _material_input(group):
    """The group's Material input, feeding Set Material (added to a group from a file made
    before it; the avatars there keep the shared material until they are loaded again)."""
    socket = group.interface.items_tree.get(MATERIAL_INPUT)
    if socket is not None:
        return socket
    socket = group.interface.new_socket(
        MATERIAL_INPUT, in_out="INPUT", socket_type="NodeSocketMaterial"
    )
    shared = gaussian_material()
    socket.default_value = shared
    inp = next(n for n in group.nodes if n.bl_idname == "NodeGroupInput")
    set_material = next(n for n in group.nodes if n.bl_idname == "GeometryNodeSetMaterial")
    group.links.new(inp.outputs[MATERIAL_INPUT], set_material.inputs["Material"])
    for obj in bpy.data.objects:  # modifiers made before the input: the shared material
        for modifier in obj.modifiers:
            if modifier.type == "NODES" and modifier.node_group is group:
                own = modifier_input(modifier, socket.identifier)
                set_modifier_input(modifier, socket.identifier, own or shared)
    return socket


def _named_attribute(nodes, name: str, data_type: str):
    node = nodes.new("GeometryNodeInputNamedAttribute")
    node.data_type = data_type
    node.inputs["Name"].default_value = name
    return node


def gaussian_material():
    """Emission of the instance's colour over a transparent BSDF, mixed by the falloff."""
    mat = bpy.data.materials.get(MATERIAL)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(MATERIAL)
    ensure_node_tree(mat)
    mat.surface_render_method = "DITHERED"  # EEVEE: order-independent, converges with samples
    mat.use_transparent_shadow = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    math = _MathBuilder(nodes, links)

    coords = nodes.new("ShaderNodeTexCoord")
    geometry = nodes.new("ShaderNodeNewGeometry")
    to_object = nodes.new("ShaderNodeVectorTransform")
    to_object.vector_type, to_object.convert_from, to_object.convert_to = (
        "VECTOR",
        "WORLD",
        "OBJECT",
    )
    links.new(geometry.outputs["Incoming"], to_object.inputs["Vector"])
    view = math.vector("NORMALIZE", to_object.outputs["Vector"])
    p = coords.outputs["Object"]  # the hit point in the instance's unit-sphere space
    along = math.vector("DOT_PRODUCT", p, view, out="Value")
    # squared distance of the ray from the centre: |p|^2 - (p . v)^2
    d2 = math.scalar(
        "SUBTRACT",
        math.vector("DOT_PRODUCT", p, p, out="Value"),
        math.scalar("MULTIPLY", along, along),
    )
    falloff = math.scalar("EXPONENT", math.scalar("MULTIPLY", d2, -0.5 * SIGMA_EXTENT**2))
    opacity = _instancer_attribute(nodes, "opacity").outputs["Fac"]
    front = math.scalar("SUBTRACT", 1.0, geometry.outputs["Backfacing"])
    alpha = math.scalar("MULTIPLY", math.scalar("MULTIPLY", falloff, opacity), front)

    colour = _instancer_attribute(nodes, "colour")
    view_colour = _instancer_attribute(nodes, "colour_view")
    pick = nodes.new("ShaderNodeMix")  # colour_view where present (its alpha is 1, else 0)
    pick.data_type = "RGBA"
    links.new(view_colour.outputs["Alpha"], pick.inputs["Factor"])
    links.new(colour.outputs["Color"], pick.inputs["A"])
    links.new(view_colour.outputs["Color"], pick.inputs["B"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    links.new(pick.outputs["Result"], emission.inputs["Color"])
    transparent = nodes.new("ShaderNodeBsdfTransparent")
    mix = nodes.new("ShaderNodeMixShader")
    links.new(alpha, mix.inputs["Fac"])
    links.new(transparent.outputs["BSDF"], mix.inputs[1])
    links.new(emission.outputs["Emission"], mix.inputs[2])
    output = nodes.new("ShaderNodeOutputMaterial")
    links.new(mix.outputs["Shader"], output.inputs["Surface"])
    _arrange(list(nodes))
    return mat


def _instancer_attribute(nodes, name: str):
    node = nodes.new("ShaderNodeAttribute")
    node.attribute_type = "INSTANCER"
    node.attribute_name = name
    return node


class _MathBuilder:
    """Math and Vector Math nodes from socket-or-constant operands."""

    def __init__(self, nodes, links):
        self.nodes, self.links = nodes, links

    def _node(self, kind: str, operation: str, operands, out: str):
        node = self.nodes.new(kind)
        node.operation = operation
        for socket, operand in zip(node.inputs, operands, strict=False):
            if isinstance(operand, bpy.types.NodeSocket):
                self.links.new(operand, socket)
            else:
                socket.default_value = operand
        return node.outputs[out]

    def scalar(self, operation: str, *operands):
        return self._node("ShaderNodeMath", operation, operands, "Value")

    def vector(self, operation: str, *operands, out: str = "Vector"):
        return self._node("ShaderNodeVectorMath", operation, operands, out)


def _arrange(nodes) -> None:
    """Spread nodes left to right so the editor shows them untangled."""
    for i, node in enumerate(nodes):
        node.location = (220.0 * (i % 8), -180.0 * (i // 8))
