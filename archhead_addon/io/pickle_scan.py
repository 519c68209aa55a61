"""A pickle's opcodes walked before it is unpickled, bounding what unpickling may build.

The C unpickler builds whatever the stream says: a "billion laughs" graph (a list holding
one memoized list twice, forty times over) is a few hundred bytes and becomes 2^40 elements
to anything that walks it, and deep nesting overflows the recursion of every later walk.
`scan` counts opcodes, memo entries and the stack's depth (nesting) without building
anything, and refuses a stream past the limits. Shared references are refused by the walk
over the unpickled objects (safe_pickle.resolve).
"""

from __future__ import annotations

import pickletools

MAX_OPCODES = 2_000_000  # a FLAME pickle has a few thousand; a tracker frame a few hundred
MAX_MEMO = 200_000
MAX_STACK = 10_000  # the pickler batches 1,000 items per APPENDS/SETITEMS
MAX_DEPTH = 64  # containers within containers (arrays bring at most a few)


class PickleLimitError(ValueError):
    """The pickle exceeds one of the limits above; the text says which."""


def scan(data: bytes) -> None:
    """Raise PickleLimitError (or ValueError for a malformed stream) past the limits."""
    stack = 0
    marks: list[int] = []
    memo = 0
    mark = pickletools.markobject
    for count, (op, arg, _pos) in enumerate(pickletools.genops(data), 1):
        if count > MAX_OPCODES:
            raise PickleLimitError(f"more than {MAX_OPCODES} pickle opcodes")
        before = op.stack_before
        if mark in before:  # pops everything down to the last mark, and the mark
            if not marks:
                raise ValueError(f"opcode {op.name} without a mark")
            stack = marks.pop()
            before = before[: before.index(mark)]
        stack -= len(before)
        if op.name == "MARK":
            marks.append(stack)
        else:
            stack = max(stack, 0) + len(op.stack_after)
        if op.name in ("PUT", "BINPUT", "LONG_BINPUT", "MEMOIZE"):
            # Picklers number entries 0, 1, 2...; the unpickler sizes its memo table by the
            # largest index, so one LONG_BINPUT of 2^31 would allocate 16 GiB.
            if op.name != "MEMOIZE" and not (isinstance(arg, int) and 0 <= arg <= memo):
                raise PickleLimitError(f"memo index {arg!r:.20} out of sequence")
            memo += 1
            if memo > MAX_MEMO:
                raise PickleLimitError(f"more than {MAX_MEMO} memo entries")
        if stack + len(marks) > MAX_STACK or len(marks) > MAX_DEPTH:
            raise PickleLimitError(
                f"nesting deeper than this reader accepts (stack {stack}, marks {len(marks)})"
            )
