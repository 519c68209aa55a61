"""Differences between the Blender versions the add-on supports (4.2 LTS through 5.0) that
more than one module meets. (Actions, whose F-curves moved into channelbags in 5.0, are
keyframes.py's.)"""

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
