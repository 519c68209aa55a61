"""Reading and resizing training images: PNG / JPG through Pillow, EXR through OpenEXR.

Colour comes out (H,W,3) float32 in [0,1], sRGB-encoded like the PNG and JPG frames: EXR
holds linear light, so it is clipped to [0,1] and encoded with the sRGB curve. Masks come out
(H,W) float32 in [0,1]: grey images as they are, colour images by their luminance (masks
saved as RGB have equal channels), EXR by its Y, R or A channel. 16-bit grey PNGs keep their
precision; Pillow reads 16-bit colour PNGs as 8-bit. A PNG or JPG comes out turned as its EXIF
orientation says (a phone stores a portrait photo sideways with an orientation to show it by),
as viewers and OpenCV show it. Every failure to read is an InputError naming the file.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..io.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr")
_EXR_MASK_CHANNELS = ("Y", "R", "A")
EXIF_ORIENTATION = 0x0112  # 1: as stored; 2-8: mirrored and/or turned; 5-8 swap width and height


def _is_exr(path: Path) -> bool:
    return path.suffix.lower() == ".exr"


def _unreadable(path, exc: Exception) -> InputError:
    return InputError(path, None, f"unreadable image ({type(exc).__name__}: {exc})")


def image_size(path) -> tuple[int, int]:
    """(H, W) from the file's header, without decoding the pixels."""
    path = Path(path)
    try:
        if _is_exr(path):
            import OpenEXR

            with OpenEXR.File(str(path), header_only=True) as f:
                lo, hi = f.header()["dataWindow"]
            return int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1)
        from PIL import Image

        with Image.open(path) as im:
            turned = _orientation(im) in (5, 6, 7, 8)
            return (im.width, im.height) if turned else (im.height, im.width)
    except (OSError, RuntimeError, ValueError, SyntaxError, KeyError) as exc:
        raise _unreadable(path, exc) from exc


def _exr_channels(path: Path) -> dict[str, np.ndarray]:
    """Channels by their last name component ('ViewLayer.Combined.R' -> 'R')."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            channels = {name: np.asarray(c.pixels, np.float32) for name, c in f.channels().items()}
    except (OSError, RuntimeError, ValueError) as exc:
        raise _unreadable(path, exc) from exc
    short = {name.rsplit(".", 1)[-1]: name for name in channels}
    if len(short) != len(channels):
        raise InputError(
            path, None, f"several layers ({', '.join(sorted(channels))}); write one layer per image"
        )
    return {s: channels[name] for s, name in short.items()}


def _srgb_encode(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _orientation(im) -> int:
    """The EXIF orientation of a Pillow image, 1 (as stored) where it has none or a bad one
    (a truncated file's pixels fail with their own error when they are read)."""
    try:
        value = im.getexif().get(EXIF_ORIENTATION, 1)
    except (OSError, ValueError, SyntaxError, struct.error):
        return 1
    return value if value in range(1, 9) else 1


def _pil_array(path: Path, colour: bool):
    """Pixels as float32 in [0,1]: (H,W,3) plus alpha (H,W) or None if colour, else (H,W)."""
    from PIL import Image, ImageOps

    try:
        with Image.open(path) as opened:
            opened.load()
            im = ImageOps.exif_transpose(opened) if _orientation(opened) != 1 else opened
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):  # 16-bit grey
                grey = np.asarray(im, dtype=np.float32) / 65535.0
                return (np.repeat(grey[..., None], 3, 2), None) if colour else grey
            if im.mode == "F":
                grey = np.asarray(im, dtype=np.float32)
                return (np.repeat(grey[..., None], 3, 2), None) if colour else grey
            if not colour:
                return np.asarray(im.convert("L"), dtype=np.float32) / 255.0
            has_alpha = "A" in im.getbands() or "transparency" in im.info
            rgba = np.asarray(im.convert("RGBA" if has_alpha else "RGB"), np.float32) / 255.0
    except (OSError, ValueError, SyntaxError) as exc:
        raise _unreadable(path, exc) from exc
    return rgba[..., :3], (rgba[..., 3] if has_alpha else None)


def read_image(path) -> tuple[np.ndarray, np.ndarray | None]:
    """(rgb (H,W,3), alpha (H,W) or None), float32 in [0,1], rgb sRGB-encoded."""
    path = Path(path)
    if not _is_exr(path):
        return _pil_array(path, colour=True)
    channels = _exr_channels(path)
    if all(c in channels for c in "RGB"):
        rgb = np.stack([channels[c] for c in "RGB"], axis=-1)
    elif "Y" in channels:
        rgb = np.repeat(channels["Y"][..., None], 3, axis=-1)
    else:
        raise InputError(path, None, f"no R, G, B or Y channels (found {sorted(channels)})")
    alpha = np.clip(channels["A"], 0.0, 1.0) if "A" in channels else None
    return _srgb_encode(rgb).astype(np.float32), alpha


def read_mask(path) -> np.ndarray:
    """A mask (H,W) float32 in [0,1]."""
    path = Path(path)
    if not _is_exr(path):
        return np.clip(_pil_array(path, colour=False), 0.0, 1.0)
    channels = _exr_channels(path)
    for name in _EXR_MASK_CHANNELS:
        if name in channels:
            return np.clip(channels[name], 0.0, 1.0)
    if len(channels) == 1:
        return np.clip(next(iter(channels.values())), 0.0, 1.0)
    raise InputError(path, None, f"no Y, R or A channel for a mask (found {sorted(channels)})")


def resize(pixels: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize (H,W) or (H,W,C) to size = (H', W') as float32, each axis on its own, pixel i
    covering [i, i + 1) on both sides (so a point at x maps to x * W' / W). Shrinking, each
    output pixel is the mean of the input area it covers (exact overlaps, any factor);
    enlarging, bilinear between the two input centres around the output centre, the edges
    held. OpenCV's area and bilinear resampling are exactly these, in float32: 4-20x the
    speed of the same weights as dense matrix products, which a full-HD frame made the
    tracker's slowest part after the fits (docs/tracking.md, "resampling the frames")."""
    import cv2

    h, w = size
    out = np.ascontiguousarray(pixels, np.float32)
    for axis, n_out in ((1, w), (0, h)):
        n_in = out.shape[axis]
        if n_in != n_out:
            target = (n_out, out.shape[0]) if axis == 1 else (out.shape[1], n_out)
            kind = cv2.INTER_AREA if n_out < n_in else cv2.INTER_LINEAR
            out = cv2.resize(out, target, interpolation=kind)
    return out.reshape(h, w, *np.shape(pixels)[2:])  # OpenCV drops a single channel's axis
