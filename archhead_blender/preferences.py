"""Add-on preferences: which FLAME model file, which Python runs the training backend."""

import bpy

# The extension's package name (bl_ext.<repo>.archhead when installed as an extension).
ADDON_PACKAGE = __package__.rsplit(".", 1)[0]


class ArchHeadPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

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
    addon = context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon else None
