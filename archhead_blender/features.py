"""Features that need a compiled part which a platform's build may lack: the add-on loads
without them and says which feature is missing and why."""

from __future__ import annotations

import functools

from archhead_addon.splat.kernel import KernelNotBuiltError, library

EXACT_SPLAT = "Exact splat renders (batch --exact, the demo's clip)"


@functools.cache  # a fact of this installation; checking it hashes the kernel sources
def missing_kernel() -> str | None:
    """None when the splat kernel loads, else a sentence naming the feature that needs it."""
    try:
        library()
    except (KernelNotBuiltError, OSError) as exc:
        return f"{EXACT_SPLAT} need the compiled splat kernel: {exc}"
    return None
