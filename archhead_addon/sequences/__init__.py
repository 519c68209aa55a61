"""Tracked FLAME sequences: readers of the trackers' formats into one canonical `Sequence`."""

from .canonical import FORMAT_VERSION, read_canonical, write_canonical
from .formats import FORMAT_NAMES, detect_format, read_sequence
from .sequence import Sequence

__all__ = [
    "FORMAT_NAMES",
    "FORMAT_VERSION",
    "Sequence",
    "detect_format",
    "read_canonical",
    "read_sequence",
    "write_canonical",
]
