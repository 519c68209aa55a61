"""Which frames to decode, and which decoded frame a held frame shows."""

from __future__ import annotations

import bisect
import re

_RANGE = re.compile(r"^\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*(?::\s*(\d+)\s*)?)?$")


def parse_frames(text: str) -> list[int]:
    """ "1-20", "1-20:5,30", "7": sorted unique frames (ranges inclusive, ':N' a stride)."""
    frames: set[int] = set()
    for part in text.split(","):
        m = _RANGE.match(part)
        if not m:
            raise ValueError(
                f"bad frame range {part.strip()!r} in {text!r} (expected e.g. 1-20, 1-20:5 or 7)"
            )
        first = int(m[1])
        last = int(m[2]) if m[2] is not None else first
        step = int(m[3] or 1)
        if last < first or step < 1:
            raise ValueError(f"empty frame range {part.strip()!r}")
        frames.update(range(first, last + 1, step))
    return sorted(frames)


def frames_to_decode(mode: str, start: int, end: int, keyed=(), stride: int = 1) -> list[int]:
    """mode KEYED: the keyed frames within [start, end] (the ends included, so the whole range
    has a decoded frame to hold); ALL: every frame; STRIDE: every stride-th from start."""
    if end < start:
        return []
    if mode == "ALL":
        return list(range(start, end + 1))
    if mode == "STRIDE":
        return list(range(start, end + 1, max(int(stride), 1)))
    if mode == "KEYED":
        inside = {round(f) for f in keyed if start <= round(f) <= end}
        return sorted(inside | {start})
    raise ValueError(f"unknown decode mode {mode!r}")


def held_frame(decoded: list[int], frame: int) -> int | None:
    """The decoded frame shown at `frame` when holding: the last one at or before it (the
    first one before the first); None when nothing is decoded. `decoded` is sorted."""
    if not decoded:
        return None
    i = bisect.bisect_right(decoded, frame)
    return decoded[max(i - 1, 0)]


def contiguous_runs(frames) -> list[tuple[int, int]]:
    """Sorted frames as (first, last) runs of consecutive frames."""
    runs: list[list[int]] = []
    for frame in sorted(set(frames)):
        if runs and frame == runs[-1][1] + 1:
            runs[-1][1] = frame
        else:
            runs.append([frame, frame])
    return [(a, b) for a, b in runs]
