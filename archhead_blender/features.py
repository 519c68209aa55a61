"""Features that need a compiled part which a platform's build may lack: the add-on loads
without them and says which feature is missing and why."""

from __future__ import annotations

import functools

from archhead_addon.splat.build import unavailable_reason

EXACT_SPLAT = "Exact splat renders (batch --exact, the demo's clip)"


@functools.cache  # a fact of this installation; checking it hashes the kernel sources
def missing_kernel() -> str | None:
    """None when the splat kernel is built or can be compiled on first use, else a sentence
    naming the feature that needs it."""
    reason = unavailable_reason()
    return f"{EXACT_SPLAT} need the compiled splat kernel: {reason}" if reason else None
