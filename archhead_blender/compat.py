"""Differences between the Blender versions the add-on supports (4.2 LTS through 5.x) that
more than one module meets. (Actions, whose F-curves moved into channelbags in 5.0, are
keyframes.py's.)

A Geometry Nodes modifier's input values: up to 5.1 they are ID properties of the modifier
itself, keyed by the group input's identifier (`modifier[identifier]`, `modifier.get(...)`).
From 5.2 the modifier takes no ID properties at all (`modifier.get` raises "TypeError: this
type doesn't support IDProperties"); each input is a struct of its own,
`modifier.properties.inputs.<identifier>`, whose `value` is the input's value (with `type`,
VALUE or ATTRIBUTE, and `attribute_name` for field inputs). `modifier_input`,
`has_modifier_input` and `set_modifier_input` are the only code that knows either way."""

from __future__ import annotations


def ensure_node_tree(id_data):
    """The node tree of a new material or world. Before Blender 5.0 one has none until
    `use_nodes` is switched on; 5.0 always has one and deprecates the switch."""
    if id_data.node_tree is None:
        id_data.use_nodes = True
    return id_data.node_tree


def eevee_engine() -> str:
    """EEVEE's engine name in this Blender: BLENDER_EEVEE_NEXT in 4.2-4.4, BLENDER_EEVEE
    before and again from 5.0."""
    import bpy

    items = bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items.keys()
    return "BLENDER_EEVEE_NEXT" if "BLENDER_EEVEE_NEXT" in items else "BLENDER_EEVEE"


def _input_structs(modifier):
    """5.2+: the modifier's `properties.inputs` (one struct per group input); None before."""
    properties = getattr(modifier, "properties", None)
    return getattr(properties, "inputs", None) if properties is not None else None


def has_modifier_input(modifier, identifier: str) -> bool:
    """Whether the Geometry Nodes modifier holds a value for the group input `identifier`."""
    inputs = _input_structs(modifier)
    if inputs is None:
        return identifier in modifier.keys()
    return hasattr(inputs, identifier)


def modifier_input(modifier, identifier: str, default=None):
    """The Geometry Nodes modifier's value of the group input `identifier` (None when unset,
    as an empty Material input), `default` when the modifier has no such input."""
    inputs = _input_structs(modifier)
    if inputs is None:
        return modifier.get(identifier, default)
    item = getattr(inputs, identifier, None)
    return default if item is None else item.value


def set_modifier_input(modifier, identifier: str, value) -> None:
    """Set the Geometry Nodes modifier's value of the group input `identifier`. From 5.2 the
    input must exist on the modifier's group (KeyError otherwise)."""
    inputs = _input_structs(modifier)
    if inputs is None:
        modifier[identifier] = value
        return
    item = getattr(inputs, identifier, None)
    if item is None:
        raise KeyError(f"{modifier.name}: no input {identifier!r}")
    item.value = value
