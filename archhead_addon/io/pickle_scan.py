"""A pickle's opcodes walked before it is unpickled, bounding what unpickling may build.

The C unpickler builds whatever the stream says: a "billion laughs" graph (a list holding
one memoized list twice, forty times over) is a few hundred bytes and becomes 2^40 elements
to anything that walks it, and deep nesting overflows the recursion of every later walk.
`scan` counts opcodes, memo entries and the stack's depth (nesting) without building
anything, and refuses a stream past the limits; `Budget` bounds the later walk over the
unpickled objects, which memo references (shared objects) can still multiply.
"""

from __future__ import annotations

import pickletools

MAX_OPCODES = 2_000_000  # a FLAME pickle has a few thousand; a tracker frame a few hundred
MAX_MEMO = 200_000
MAX_STACK = 10_000  # the pickler batches 1,000 items per APPENDS/SETITEMS
MAX_DEPTH = 64  # containers within containers (arrays bring at most a few)
MAX_VISITS = 1_000_000  # objects reached by walking the result, shared ones each time


class PickleLimitError(ValueError):
    """The pickle exceeds one of the limits above; the text says which."""


def scan(data: bytes) -> None:
    """Raise PickleLimitError (or ValueError for a malformed stream) past the limits."""
    stack = 0
    marks: list[int] = []
    memo = 0
    mark = pickletools.markobject
    for count, (op, _arg, _pos) in enumerate(pickletools.genops(data), 1):
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
            memo += 1
            if memo > MAX_MEMO:
                raise PickleLimitError(f"more than {MAX_MEMO} memo entries")
        if stack + len(marks) > MAX_STACK or len(marks) > MAX_DEPTH:
            raise PickleLimitError(
                f"nesting deeper than this reader accepts (stack {stack}, marks {len(marks)})"
            )


class Budget:
    """Counts objects visited by a walk over unpickled data; shared objects count each time."""

    def __init__(self, visits: int = MAX_VISITS, depth: int = MAX_DEPTH):
        self.left, self.depth = visits, depth

    def visit(self, depth: int) -> None:
        self.left -= 1
        if self.left < 0:
            raise PickleLimitError(
                f"the pickle's objects reach more than {MAX_VISITS} others "
                "(shared references multiplying them: a 'billion laughs' graph?)"
            )
        if depth > self.depth:
            raise PickleLimitError(f"containers nested deeper than {self.depth}")
