"""ArchHead Blender extension: registration only. The operator classes live in operators/,
the UI in panels/, everything else Blender-side in the `archhead_blender` package and the
core in `archhead_addon` (both installed from the extension's wheel, so every process
imports them under these names).

Submodules are imported in register(), so importing this package alone (test collectors,
tooling) has no side effects and needs no Blender.
"""


def register():
    import archhead_blender

    from . import operators, panels

    archhead_blender.register(__package__)
    operators.register()
    panels.register()


def unregister():
    import archhead_blender

    from . import operators, panels

    panels.unregister()
    operators.unregister()
    archhead_blender.unregister()
