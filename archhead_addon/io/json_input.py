"""JSON files from users (camera transforms, training configs), read with bounds: a size
limit, and nesting that would overflow the parser's recursion refused as an InputError."""

from __future__ import annotations

import json
from pathlib import Path

from .errors import InputError

MAX_JSON_BYTES = 256 << 20  # a transforms.json of 100,000 frames is about 60 MB


def load_json(path, max_bytes: int = MAX_JSON_BYTES):
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise InputError(path, None, f"{size} bytes, above the {max_bytes} read as JSON")
        return json.loads(path.read_text(encoding="utf-8"))
    except InputError:
        raise
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise InputError(path, None, f"not a readable JSON file ({exc})") from exc
    except RecursionError as exc:
        raise InputError(path, None, "not a readable JSON file (nested too deeply)") from exc


def json_number(value, path, key, *, minimum=None) -> float:
    """A JSON number (not a bool), finite, at least `minimum`."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not ok or not abs(value) <= 1.7e308:  # also False for NaN
        raise InputError(path, key, f"missing or not a finite number ({value!r:.40})")
    if minimum is not None and value < minimum:
        raise InputError(path, key, f"expected at least {minimum}, found {value}")
    return value
