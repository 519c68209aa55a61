"""ArchHead's Blender-side library: everything that runs inside Blender except the operator
classes (operators/) and the UI (panels/). Imports bpy and the core (`archhead_addon`), never
torch; heavy work runs in the backend process.

Runtime state lives in `state` alone. Scripts and benchmarks use `api`, the public surface.
"""


def register(addon_package: str) -> None:
    """Preferences (under the add-on's module name), the avatar settings, the handlers.
    Thread variables above the cores are lowered first: the splat kernel's OpenMP and the
    backends started from here read them."""
    from archhead_addon.threads import limit_thread_environment

    from . import avatar_props, features, handlers, preferences

    limit_thread_environment()
    preferences.register(addon_package)
    avatar_props.register()
    handlers.register()
    missing = features.missing_kernel()
    if missing:
        print(f"ArchHead: {missing}")


def unregister() -> None:
    from . import avatar_props, handlers, preferences, state

    handlers.unregister()
    state.reset(keep_models=False)  # also stops a running training backend (it saves)
    avatar_props.unregister()
    preferences.unregister()
