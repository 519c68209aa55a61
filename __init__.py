"""ArchHead Blender extension: registration only; the work lives in operators/ and panels/.

Blender-side code uses numpy and this package's `archhead_addon` core, never torch.
Submodules are imported in register(), so importing this package alone (test collectors,
tooling) has no side effects and needs no Blender.
"""


def register():
    from . import operators, panels

    panels.register_preferences()
    operators.register()
    panels.register()


def unregister():
    from . import operators, panels

    panels.unregister()
    operators.unregister()
    panels.unregister_preferences()
