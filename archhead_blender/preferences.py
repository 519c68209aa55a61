"""Add-on preferences: which FLAME model file, which Python runs the training backend, how
much memory all avatars' decoded frames may take."""

import bpy

# Decoded frames in memory, all avatars together: 64 full-size heads at LOD 0 add 340 MB a
# frame, so a crowd played back without a total would pass the machine's memory.
MEMORY_TOTAL_MB = 2048


def _memory_changed(_prefs, _context) -> None:
    from .avatar_session import balance_memory  # avatar_session imports this module

    balance_memory()


class ArchHeadPreferences(bpy.types.AddonPreferences):
    # Set by register(): the add-on's module name, which Blender chooses per repository
    # (bl_ext.<repo>.archhead), so it cannot be spelled here.
    bl_idname = "archhead"

    flame_model_path: bpy.props.StringProperty(
        name="FLAME model",
        description="FLAME 2020 / 2023 generic_model.pkl or a FLAME-format .npz; "
        "empty uses the built-in model",
        subtype="FILE_PATH",
    )
    backend_python: bpy.props.StringProperty(
        name="Backend Python",
        description="Python executable of the environment with torch, used to train avatars",
        subtype="FILE_PATH",
    )

    memory_total_mb: bpy.props.IntProperty(
        name="Memory for all avatars (MB)",
        min=64,
        default=MEMORY_TOTAL_MB,
        update=_memory_changed,
        description="Decoded frames kept in memory by all avatars together (each avatar's "
        "own Memory cache applies within it): a crowd's frames pass the machine's memory "
        "without it",
    )

    def draw(self, context):
        self.layout.prop(self, "flame_model_path")
        self.layout.prop(self, "backend_python")
        self.layout.prop(self, "memory_total_mb")


def get_preferences(context) -> ArchHeadPreferences | None:
    addon = context.preferences.addons.get(ArchHeadPreferences.bl_idname)
    return addon.preferences if addon else None


def memory_total_bytes(context=None) -> int:
    prefs = get_preferences(context or bpy.context)
    return (prefs.memory_total_mb if prefs else MEMORY_TOTAL_MB) << 20


def register(addon_package: str) -> None:
    ArchHeadPreferences.bl_idname = addon_package
    bpy.utils.register_class(ArchHeadPreferences)


def unregister() -> None:
    bpy.utils.unregister_class(ArchHeadPreferences)
