"""A minimal PNG encoder (8-bit grey, RGB or RGBA; numpy and zlib only), so the Blender-side
script writes frames and masks without Pillow, which Blender's Python lacks."""

from __future__ import annotations

import struct
import zlib

import numpy as np

_COLOUR_TYPES = {1: 0, 3: 2, 4: 6}  # channels -> PNG colour type (grey, RGB, RGBA)


def _chunk(kind: bytes, data: bytes) -> bytes:
    return (
        struct.pack(">I", len(data))
        + kind
        + data
        + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    )


def encode_png(pixels: np.ndarray, level: int = 6) -> bytes:
    """PNG bytes of uint8 pixels (H,W), (H,W,1), (H,W,3) or (H,W,4), top row first."""
    a = np.asarray(pixels)
    if a.dtype != np.uint8:
        raise ValueError(f"expected uint8 pixels, found {a.dtype}")
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in _COLOUR_TYPES or 0 in a.shape:
        raise ValueError(f"expected (H,W) or (H,W,1|3|4) pixels, found {a.shape}")
    h, w, c = a.shape
    rows = np.concatenate([np.zeros((h, 1), np.uint8), a.reshape(h, w * c)], axis=1)  # filter 0
    header = struct.pack(">IIBBBBB", w, h, 8, _COLOUR_TYPES[c], 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", header)
        + _chunk(b"IDAT", zlib.compress(rows.tobytes(), level))
        + _chunk(b"IEND", b"")
    )
