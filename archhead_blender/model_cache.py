"""The head model in use (FLAME file from the preferences or the built-in one), with teeth.

Loaded once per path per session: reading a FLAME pickle takes a moment.
"""

from __future__ import annotations

from archhead_addon.flame.model import FlameModel, load_model
from archhead_addon.flame.teeth import add_teeth

from .state import STATE


def head_model(path: str = "") -> FlameModel:
    key = str(path or "")
    if key not in STATE.head_models:
        STATE.head_models[key] = add_teeth(load_model(key or None))
    return STATE.head_models[key]
