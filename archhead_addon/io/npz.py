"""npz archives read member by member, each npy header checked before its array exists.

`np.load` allocates whatever a header claims (a few bytes can claim a 224 GiB array) and
lets zipfile's own errors escape. Here every member's header must describe exactly the bytes
the member holds, in a plain dtype (no objects, no complex numbers, no records), before the
array is read; every failure is an InputError naming the file and the key.
"""

from __future__ import annotations

import io
import math
import tokenize
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .errors import InputError
from .zip_check import DEFAULT_MAX_BYTES, open_checked

_KINDS = "biufUS"  # bool, integers, floats, text and bytes
_MAX_HEADER = 1 << 16
_READ_ERRORS = (zipfile.BadZipFile, zlib.error, OSError, ValueError, EOFError, KeyError)


def read_npz(
    path, max_bytes: int = DEFAULT_MAX_BYTES, what: str = "npz archive"
) -> dict[str, np.ndarray]:
    """Every array of the npz at `path` by key; InputError on anything malformed (`what`
    names the file's kind when it is no zip archive at all)."""
    path = Path(path)
    try:
        if not path.is_file():
            raise InputError(path, None, "file not found")
        with open(path, "rb") as f:
            magic = f.read(6)
    except OSError as exc:  # a name too long for the system, no permission
        raise InputError(path, None, f"unreadable ({exc.strerror or exc})") from exc
    if magic == b"\x93NUMPY":
        raise InputError(path, None, "a single .npy array, not an npz archive")
    with open_checked(path, max_bytes, what) as archive:
        return {
            info.filename[: -len(".npy")]: _member(archive, info, path)
            for info in archive.infolist()
            if not info.filename.endswith("/")
        }


def _member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, path) -> np.ndarray:
    key = info.filename[: -len(".npy")] if info.filename.endswith(".npy") else info.filename
    if not info.filename.endswith(".npy"):
        raise InputError(path, key, "not an .npy member")
    try:
        with archive.open(info) as f:
            head = io.BytesIO(f.read(min(info.file_size, _MAX_HEADER + 16)))
        shape, fortran, dtype = _header(head)
    except InputError:
        raise
    except _READ_ERRORS + (
        SyntaxError,
        TypeError,
        IndexError,
        UnicodeDecodeError,
        tokenize.TokenError,
    ) as exc:  # a garbled header's Python literal fails in numpy's tokenizer (TokenError)
        raise InputError(
            path, key, f"unreadable npy header (corrupt file? {type(exc).__name__}: {exc})"
        ) from exc
    if dtype.hasobject or dtype.kind not in _KINDS or dtype.fields or dtype.subdtype:
        raise InputError(path, key, f"dtype {dtype} is not accepted (numbers and text only)")
    claimed = math.prod(shape) * dtype.itemsize
    held = info.file_size - head.tell()
    if claimed != held:
        raise InputError(
            path,
            key,
            f"header claims shape {shape} of {dtype} ({claimed} bytes), "
            f"the member holds {held} bytes",
        )
    try:
        buffer = bytearray(held)  # the one allocation, of the size just checked
        with archive.open(info) as f:
            f.seek(head.tell())
            view, done = memoryview(buffer), 0
            while done < held:
                n = f.readinto(view[done:])
                if not n:
                    raise EOFError(f"member ends after {done} of {held} bytes")
                done += n
            f.read(1)  # reaching the end checks the member's CRC
        return np.frombuffer(buffer, dtype=dtype).reshape(shape, order="F" if fortran else "C")
    except _READ_ERRORS as exc:  # a damaged member fails its CRC here
        raise InputError(path, key, f"unreadable (corrupt file?): {exc}") from exc


def _header(f) -> tuple[tuple[int, ...], bool, np.dtype]:
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(f, max_header_size=_MAX_HEADER)
    if version == (2, 0):
        return np.lib.format.read_array_header_2_0(f, max_header_size=_MAX_HEADER)
    raise ValueError(f"npy format version {version} is not read")
