"""The avatar's settings, stored on its point object (`Object.archhead_avatar`).

`lod` is an ordinary animatable float: keyframes, drivers and the N-panel slider all reach
it, and the handlers re-decode whenever its evaluated value changes. Settings that change
what is shown tag the object, so the depsgraph (and with it the handlers) sees the change.
"""

from __future__ import annotations

import bpy


def _tag(self, _context):
    """A Python-defined property does not tag its object for the depsgraph by itself: without
    this the evaluated copy (which handlers and renders read) keeps the old value."""
    self.id_data.update_tag()


class ArchHeadAvatarSettings(bpy.types.PropertyGroup):
    checkpoint: bpy.props.StringProperty(
        update=_tag,
        name="Checkpoint",
        subtype="FILE_PATH",
        description="The avatar checkpoint (.npz) this object shows",
    )
    head: bpy.props.PointerProperty(
        update=_tag,
        name="Head",
        type=bpy.types.Object,
        description="The imported head whose shape keys and bones drive the avatar",
    )
    lod: bpy.props.FloatProperty(
        update=_tag,
        name="Level of detail",
        min=0.0,
        max=1.0,
        default=0.0,
        precision=3,
        description="0 = most detail (UV resolution 256), 1 = least (64); animatable",
    )
    decode_frames: bpy.props.EnumProperty(
        name="Decode",
        default="KEYED",
        items=(
            (
                "KEYED",
                "Keyed frames",
                "Frames that carry a key of the head, its rig or the "
                "level of detail, in the scene's range",
            ),
            ("ALL", "Every frame", "Every frame of the scene's range"),
            ("STRIDE", "Every n-th frame", "Every n-th frame of the scene's range"),
        ),
    )
    stride: bpy.props.IntProperty(name="Stride", min=1, default=5)
    between: bpy.props.EnumProperty(
        update=_tag,
        name="Between decoded frames",
        default="LIVE",
        items=(
            (
                "LIVE",
                "Decode live",
                "Decode the codes the scene has at the frame: Blender "
                "interpolates them between keys",
            ),
            ("HOLD", "Hold", "Show the last decoded frame until the next one"),
        ),
    )
    identity: bpy.props.EnumProperty(
        update=_tag,
        name="Identity",
        default="HEAD",
        items=(
            (
                "HEAD",
                "Head",
                "The imported head's identity shape (the avatar sits on the head's mesh)",
            ),
            (
                "AVATAR",
                "Avatar",
                "The identity the avatar was trained with (reenactment "
                "with another person's tracking)",
            ),
        ),
    )
    view_dependent: bpy.props.BoolProperty(
        update=_tag,
        name="View-dependent colour",
        default=True,
        description="For avatars with spherical-harmonic colour: evaluate it towards the "
        "scene camera each frame, as the exact splat render does (off: the DC colour alone, "
        "decoded and cached without the higher bands). Avatars with one colour per Gaussian "
        "look the same either way",
    )
    cull: bpy.props.EnumProperty(
        update=_tag,
        name="Culling",
        default="RENDER",
        description="Leave out, before decoding, the Gaussians the scene camera cannot see",
        items=(
            ("OFF", "Off", "Decode and draw every Gaussian"),
            (
                "RENDER",
                "Renders",
                "Cull in renders (F12, batch, exact splat); the viewport shows the whole "
                "avatar, to orbit around",
            ),
            (
                "ALWAYS",
                "Always",
                "Cull in the viewport too (for looking through the camera)",
            ),
        ),
    )
    disk_cache: bpy.props.BoolProperty(
        update=_tag,
        name="Cache on disk",
        default=False,
        description="Keep decoded frames in a folder next to the .blend (shared by renders "
        "and render-farm machines)",
    )
    cache_dir: bpy.props.StringProperty(
        update=_tag,
        name="Cache folder",
        subtype="DIR_PATH",
        default="//archhead_cache",
        description="Folder of the disk cache ('//' is the .blend's folder); files are named "
        "by avatar, codes and level of detail, so avatars and machines can share it",
    )
    memory_mb: bpy.props.IntProperty(
        update=_tag,
        name="Memory cache (MB)",
        min=16,
        default=1024,
        description="Decoded frames kept in memory, least recently used dropped first",
    )


def _tag_avatars(self, context):
    """A scene setting that changes every avatar's level of detail: refresh them all."""
    for obj in self.id_data.objects:
        if is_avatar(obj):
            obj.update_tag()


class ArchHeadCrowdSettings(bpy.types.PropertyGroup):
    """What a scene of many avatars sets once for all of them (`Scene.archhead_crowd`)."""

    lod_bias: bpy.props.FloatProperty(
        update=_tag_avatars,
        name="LOD bias",
        min=-1.0,
        max=1.0,
        default=0.0,
        precision=3,
        description="Added to the level of detail of every avatar driven by camera distance "
        "(positive: less detail everywhere); animatable",
    )
    gaussian_budget: bpy.props.IntProperty(
        update=_tag_avatars,
        name="Gaussian budget",
        min=0,
        default=0,
        description="The most Gaussians the scene's avatars may show at once: above it, every "
        "avatar's level of detail is raised by one common amount until they fit (0: no limit)",
    )


def register():
    bpy.utils.register_class(ArchHeadAvatarSettings)
    bpy.utils.register_class(ArchHeadCrowdSettings)
    bpy.types.Object.archhead_avatar = bpy.props.PointerProperty(type=ArchHeadAvatarSettings)
    bpy.types.Scene.archhead_crowd = bpy.props.PointerProperty(type=ArchHeadCrowdSettings)


def unregister():
    del bpy.types.Scene.archhead_crowd
    del bpy.types.Object.archhead_avatar
    bpy.utils.unregister_class(ArchHeadCrowdSettings)
    bpy.utils.unregister_class(ArchHeadAvatarSettings)


def is_avatar(obj) -> bool:
    return obj is not None and obj.type == "MESH" and bool(obj.archhead_avatar.checkpoint)
