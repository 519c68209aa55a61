"""Frames from a video file, a folder of numbered images or a single image, as RGB uint8.

Video is decoded with OpenCV (FFmpeg inside its wheel), turned upright as the file's
rotation says (a phone's portrait video is stored sideways with a rotation to show it by, and
OpenCV 4.11 stopped applying it by default; images are turned by their EXIF orientation in
`train.images`). A file OpenCV cannot open, or one that yields no frame, is an InputError
naming it; a video that ends before the frame count its header claims (truncated) is used up
to where it ends, with a warning, and one whose header has no count is counted.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.errors import InputError, warn_input
from ..train.dataset import numbered_images
from ..train.images import IMAGE_SUFFIXES, read_image

DEFAULT_FPS = 25.0
# A header's frame count above this (65 hours at 70 fps) is not a count: a stream without a
# duration (a browser's or a live recorder's WebM or MKV) reads as -2e17 or so.
MAX_FRAME_COUNT = 1 << 24


@dataclass
class FrameSource:
    path: Path
    fps: float
    count: int  # frames expected (a video header's count may overstate a truncated file)
    kind: str  # "video", "images" or "image"
    _files: list | None = None

    def frames(self, limit: int | None = None, stride: int = 1) -> Iterator[tuple[int, np.ndarray]]:
        """(frame number, RGB (H,W,3) uint8) in order: every `stride`-th of the first `limit`
        frames (the first one first)."""
        limit = self.count if limit is None else min(limit, self.count)
        if self.kind == "video":
            yield from _video_frames(self.path, limit, stride)
            return
        for number, path in self._files[:limit:stride]:
            rgb, _ = read_image(path)
            yield number, np.round(rgb[..., :3] * 255).astype(np.uint8)


def open_frames(path) -> FrameSource:
    path = Path(path)
    if not path.exists():
        raise InputError(
            path, None, "not found: expected a video file, a folder of numbered images or an image"
        )
    if path.is_dir():
        files = numbered_images(path)
        return FrameSource(path, DEFAULT_FPS, len(files), "images", files)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        return FrameSource(path, DEFAULT_FPS, 1, "image", [(0, path)])
    import cv2

    capture = _capture(path)
    try:
        if not capture.isOpened():
            raise InputError(
                path,
                None,
                "not a video OpenCV can decode (and not a PNG, JPG or "
                "EXR image or a folder of them)",
            )
        fps = capture.get(cv2.CAP_PROP_FPS)
        count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
        ok, _ = capture.read()
        if ok and not (np.isfinite(count) and 1 <= count <= MAX_FRAME_COUNT):
            count = 1 + _frames_left(capture)  # no count in the header: counted
    finally:
        capture.release()
    if not ok:
        raise InputError(path, None, "the video has no frame that can be decoded")
    if not np.isfinite(fps) or not 1 <= fps <= 1000:
        warn_input(path, "fps", f"implausible frame rate {fps!r}; using {DEFAULT_FPS:g}")
        fps = DEFAULT_FPS
    return FrameSource(path, float(fps), int(count), "video")


def _frames_left(capture) -> int:
    """The frames a capture has left, each decoded once (no pixels converted)."""
    n = 0
    while capture.grab():
        n += 1
    return n


def _capture(path: Path):
    """An OpenCV capture of `path` that turns the frames as the file's rotation says."""
    import cv2

    capture = cv2.VideoCapture(str(path))
    capture.set(cv2.CAP_PROP_ORIENTATION_AUTO, 1)
    return capture


def _video_frames(path: Path, limit: int, stride: int) -> Iterator[tuple[int, np.ndarray]]:
    import cv2

    capture = _capture(path)
    number = 0
    try:
        while number < limit:
            if number % stride:  # decoded (frames depend on earlier ones), not converted
                if not capture.grab():
                    break
                number += 1
                continue
            ok, bgr = capture.read()
            if not ok:
                break
            yield number, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            number += 1
    finally:
        capture.release()
    if number < limit:
        warn_input(
            path,
            None,
            f"the video ended after {number} of the {limit} frames its "
            "header announces (truncated?); using those",
        )
