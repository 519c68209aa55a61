"""Add-on preferences: which FLAME model file, which Python runs the training backend."""

import bpy


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

    def draw(self, context):
        self.layout.prop(self, "flame_model_path")
        self.layout.prop(self, "backend_python")


def get_preferences(context) -> ArchHeadPreferences | None:
    addon = context.preferences.addons.get(ArchHeadPreferences.bl_idname)
    return addon.preferences if addon else None


def register(addon_package: str) -> None:
    ArchHeadPreferences.bl_idname = addon_package
    bpy.utils.register_class(ArchHeadPreferences)


def unregister() -> None:
    bpy.utils.unregister_class(ArchHeadPreferences)
