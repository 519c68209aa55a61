"""Zip archives (npz, torch.save files) checked from their central directory before any
member is read: what Python's zipfile would fail on with a raw traceback (deflate64,
encryption), what it would silently resolve (duplicate names: the last one wins), and sizes
that no real file has (a member claiming more than deflate can expand to, or more than the
reader's limit) are refused with an InputError before anything is allocated. A directory
cannot understate a member either: a stored member holds exactly what it declares, a deflated
one no more compressed bytes than deflate makes of its declared size (zipfile would inflate
the rest, up to 1 GiB at a time, before cutting it to the declared size)."""

from __future__ import annotations

import os
import zipfile
from collections import Counter

from .errors import InputError

# Deflate expands at most ~1032:1; a member declaring more than this lies about its size.
MAX_DEFLATE_RATIO = 1100
# Numbers deflate a few times at most (floats barely, zero-padded columns more): the deflated
# members of an archive may inflate to this many times the file's size, or INFLATE_FLOOR,
# whichever is more. A 2 MB file claiming 2 GiB is a bomb, refused before a byte is inflated.
INFLATE_RATIO = 32
INFLATE_FLOOR = 64 << 20
DEFAULT_MAX_BYTES = 4 << 30  # a whole archive, uncompressed: far above any checkpoint
_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}


def open_checked(path, max_bytes: int = DEFAULT_MAX_BYTES, what="zip archive") -> zipfile.ZipFile:
    """The archive at `path`, its directory checked; the caller closes it. `what` names the
    kind of file in the error for one that is no zip archive at all."""
    try:
        archive = zipfile.ZipFile(path)
    except NotImplementedError as exc:  # a member's version needed to extract, past zipfile's
        raise InputError(path, None, f"{what} of a zip version Python cannot read ({exc})") from exc
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, IndexError, KeyError) as exc:
        raise InputError(path, None, f"not a readable {what} ({exc})") from exc
    try:
        check_directory(archive, path, max_bytes, os.stat(path).st_size)
    except BaseException:
        archive.close()
        raise
    return archive


def check_directory(archive: zipfile.ZipFile, path, max_bytes: int, file_size: int) -> None:
    infos = archive.infolist()
    repeated = [name for name, n in Counter(i.filename for i in infos).items() if n > 1]
    if repeated:
        raise InputError(path, repeated[0], "duplicate member name in the zip archive")
    total = deflated = 0
    for info in infos:
        name = info.filename
        if info.flag_bits & 0x41:  # traditional or strong encryption
            raise InputError(path, name, "encrypted zip member")
        if info.flag_bits & 0x20:
            raise InputError(path, name, "zip member in 'compressed patched data' form")
        if info.compress_type not in _METHODS:
            raise InputError(
                path,
                name,
                f"zip compression method {info.compress_type} is not supported "
                "(only stored and deflate)",
            )
        if info.header_offset + info.compress_size > file_size:  # zipfile would allocate it
            raise InputError(path, name, "member runs past the end of the file (truncated?)")
        if info.compress_type == zipfile.ZIP_STORED and info.compress_size != info.file_size:
            raise InputError(
                path,
                name,
                f"stored (uncompressed) member claims {info.file_size} bytes and holds "
                f"{info.compress_size}: a damaged or forged directory",
            )
        if info.compress_size > _deflate_bound(info.file_size):  # its stream goes on
            raise InputError(
                path,
                name,
                f"{info.compress_size} compressed bytes for {info.file_size} uncompressed: "
                "more than deflate makes of that size (a directory that understates it)",
            )
        if info.file_size > MAX_DEFLATE_RATIO * max(info.compress_size, 1) + 1024:
            raise InputError(
                path,
                name,
                f"claims {info.file_size} bytes from {info.compress_size} "
                "compressed: more than deflate can expand (a zip bomb or a damaged directory)",
            )
        total += info.file_size
        deflated += info.file_size if info.compress_type == zipfile.ZIP_DEFLATED else 0
    inflate_limit = max(INFLATE_FLOOR, INFLATE_RATIO * file_size)
    if deflated > inflate_limit:
        raise InputError(
            path,
            None,
            f"compressed members inflate to {deflated} bytes from a {file_size}-byte file, "
            f"above the limit of {inflate_limit} ({INFLATE_RATIO} times the file, at least "
            f"{INFLATE_FLOOR >> 20} MiB): a decompression bomb",
        )
    if total > max_bytes:
        raise InputError(
            path,
            None,
            f"members hold {total} bytes uncompressed, above this reader's limit of {max_bytes}",
        )


def _deflate_bound(size: int) -> int:
    """The most bytes deflate may take for `size` bytes: zlib's deflateBound is size + size/4096
    + size/16384 + 13 (stored blocks cost 5 bytes per 64 KiB); this is more generous."""
    return size + (size >> 10) + 64
