"""What the readers share: npz loading, key and shape checks, numbered per-frame files, fps."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np

from ..io.errors import InputError, warn_input
from ..io.npz import read_npz
from ..io.schema import check_finite, numeric
from .sequence import DEFAULT_FPS

_MISSING = object()


def load_npz(path) -> dict[str, np.ndarray]:
    """All arrays of an npz archive, each header checked before its array is read
    (io/npz.py); corrupt, truncated or pickled content is an InputError."""
    return read_npz(path)


def _describe(shape) -> str:
    return "(" + ", ".join(str(d) for d in shape) + ("," if len(shape) == 1 else "") + ")"


def get(
    arrays: dict,
    key: str,
    path,
    *shapes,
    frame=None,
    along: str | None = None,
    default=_MISSING,
    name: str | None = None,
) -> np.ndarray:
    """`arrays[key]` as float64 in one of `shapes` (ints fixed, strings any size), finite.

    A NaN/Inf error says where: `frame` names the frame of a per-frame file; `along` names what
    the first axis counts ("frame", "vertex") and the error gives that index. `name` is the key
    as errors show it (e.g. 'flame.exp' for a nested dict).
    """
    label = name or key
    if key not in arrays or arrays[key] is None:
        if default is not _MISSING:
            return default
        raise InputError(path, label, "missing")
    value = numeric(arrays[key], path, label)
    if not any(
        len(s) == value.ndim
        and all(isinstance(d, str) or d == n for d, n in zip(s, value.shape, strict=True))
        for s in shapes
    ):
        want = " or ".join(_describe(s) for s in shapes)
        raise InputError(path, label, f"expected shape {want}, found {_describe(value.shape)}")
    if frame is not None and not np.isfinite(value).all():
        raise InputError(path, label, f"NaN or Inf (frame {frame})")
    check_finite(value, path, label, along)
    return value


_NUMBERED = re.compile(r"^(.*?)(\d+)$")


def numbered_files(folder: Path, suffix: str) -> list[tuple[int, Path]]:
    """Files `<prefix><number><suffix>` in `folder`, sorted by number.

    All must share one prefix and one zero-padding, and numbers must be unique; anything else
    means files of different runs were mixed, and the error names the offending files.
    """
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.name.endswith(suffix))
    if not files:
        raise InputError(folder, None, f"no '*{suffix}' files in this folder")
    parsed = {p: _NUMBERED.match(p.name[: -len(suffix)]) for p in files}
    unnumbered = [p.name for p, m in parsed.items() if m is None]
    if unnumbered:
        raise InputError(
            folder, None, f"files without a frame number in their name: {_names(unnumbered)}"
        )
    prefixes = Counter(m.group(1) for m in parsed.values())
    if len(prefixes) > 1:
        usual = prefixes.most_common(1)[0][0]
        raise InputError(
            folder,
            None,
            f"mixed frame file names (most start with '{usual}'): "
            f"{_names(p.name for p, m in parsed.items() if m.group(1) != usual)}",
        )
    digits = {p: m.group(2) for p, m in parsed.items()}
    by_number: dict[int, list[str]] = {}
    for p, d in digits.items():
        by_number.setdefault(int(d), []).append(p.name)
    duplicates = [names for names in by_number.values() if len(names) > 1]
    if duplicates:
        raise InputError(
            folder, None, f"duplicate frame numbers: {'; '.join(_names(d) for d in duplicates)}"
        )
    padded = Counter(len(d) for d in digits.values() if len(d) > 1 and d.startswith("0"))
    if padded:
        width = padded.most_common(1)[0][0]
        odd = [
            p.name
            for p, d in digits.items()
            if len(d) < width or (d.startswith("0") and len(d) not in (1, width))
        ]
        if odd:
            raise InputError(
                folder,
                None,
                f"mixed frame numbering (most are zero-padded to {width} digits): {_names(odd)}",
            )
    return sorted((int(d), p) for p, d in digits.items())


def _names(names, limit: int = 8) -> str:
    names = list(names)
    shown = ", ".join(names[:limit])
    return shown + (f" (and {len(names) - limit} more)" if len(names) > limit else "")


def frame_number(path: Path) -> int:
    """The number a single per-frame file's name ends with (0 when there is none)."""
    match = _NUMBERED.match(path.stem)
    return int(match.group(2)) if match else 0


def resolve_fps(fps, path) -> float:
    """The caller's fps, or DEFAULT_FPS with a warning for formats that store none."""
    if fps is not None:
        return float(fps)
    warn_input(
        path,
        "fps",
        f"this format stores no frame rate; assuming {DEFAULT_FPS:g} fps "
        "(pass fps= or --fps to set it)",
    )
    return DEFAULT_FPS
