"""The tracker end to end: frames -> landmarks and masks -> FLAME fit -> training folder.

Frames are decoded twice (landmarks first, then the crop once the whole clip's face
position is known) so memory holds landmarks and masks, not the video; the person masks,
soft and mostly flat, are kept deflated (a full-HD frame's 2 MB in a few tens of kB).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..flame.model import load_model
from ..io.errors import InputError, warn_input
from ..sequences import write_canonical
from ..timing import Stopwatch
from ..train.dataset import MASKS_DIR, PERSON_MASKS_DIR, REGIONS_DIR, TRACKING_FILE
from ..train.images import read_mask, resize
from . import FRAME_BUDGET
from .detect import MAX_HAND_COVER, FaceDetector
from .embedding import landmark_embedding
from .fit import ClipFit, FitOptions, crop_intrinsics, fit_landmarks, fitted_sequence
from .folder import (
    frame_name,
    remove_stale_stages,
    staged_folder,
    write_frame,
    write_mask,
    write_report,
)
from .head_mask import head_and_neck_masks
from .media import open_frames
from .photometric import PhotometricOptions, refine_photometric

MIN_FRAMES = 2  # a training folder needs a train and a test frame
CROP_FACE_HEIGHTS = 2.6  # the square crop's side in face heights (when the frame allows)
OUTLIER_RATIO, OUTLIER_MIN_PX = 4.0, 6.0  # a frame's residual beyond both is dropped


@dataclass
class TrackOptions:
    size: int = 512
    max_frames: int | None = None  # the clip's first frames only
    frame_budget: int | None = FRAME_BUDGET  # every k-th frame beyond it; None: every frame
    focal: float | None = None  # pixels at the source frames' size
    flame: str | None = None  # a FLAME model file; None: the built-in head
    max_hand_cover: float = MAX_HAND_COVER  # 1 keeps frames with a hand over the face
    # refine the landmark fit against the frames (photometric.py); None: landmarks only
    photometric: PhotometricOptions | None = field(default_factory=PhotometricOptions)
    static_offset: bool = False  # fit a per-vertex offset of the identity (with photometric)


class _Deflated:
    """A uint8 array kept zlib-compressed: a clip's person masks at the source size would
    take 2 MB a full-HD frame, gigabytes for a phone video of a minute or two."""

    def __init__(self, array: np.ndarray):
        self.shape = array.shape
        self.data = zlib.compress(np.ascontiguousarray(array).tobytes(), 1)

    def array(self) -> np.ndarray:
        return np.frombuffer(zlib.decompress(self.data), np.uint8).reshape(self.shape)


def _square_crop(landmarks: np.ndarray, size: tuple[int, int]) -> tuple[int, int, int]:
    """(x0, y0, side): one square for the whole clip around the median face position."""
    height, width = size
    lo, hi = landmarks.min(axis=1), landmarks.max(axis=1)  # (T,2)
    centre = np.median((lo + hi) / 2, axis=0)
    face = np.median(hi[:, 1] - lo[:, 1])
    side = int(min(height, width, max(round(CROP_FACE_HEIGHTS * face), 16)))
    x0 = int(np.clip(round(centre[0] - side / 2), 0, width - side))
    y0 = int(np.clip(round(centre[1] - side / 2), 0, height - side))
    return x0, y0, side


def track(source_path, out, options: TrackOptions | None = None, progress=None) -> dict:
    """Track a video (or frames) into the training folder `out`; returns the report."""
    opt = options or TrackOptions()
    if not 16 <= opt.size <= 4096:
        raise InputError(None, "size", f"{opt.size} px is outside 16 ... 4096")
    if opt.static_offset and opt.photometric is None:
        raise InputError(
            None, "static_offset", "is fitted by the photometric refinement: keep it on"
        )
    out = Path(out).absolute()
    remove_stale_stages(out.parent)  # now, not only once a stage is made minutes later
    say = progress or (lambda **event: None)
    times = {}
    watch = Stopwatch()
    source = open_frames(source_path)
    model = load_model(opt.flame)
    embedding = landmark_embedding(model)
    times["model"] = watch.seconds

    watch = Stopwatch()
    numbers, landmarks, masks, dropped, multi = [], [], [], [], 0
    size = None
    total = source.count if opt.max_frames is None else min(opt.max_frames, source.count)
    stride = frame_stride(total, opt.frame_budget)
    chosen = math.ceil(total / stride)

    def frames():  # every frame the size of the first
        nonlocal size
        for number, rgb in source.frames(total, stride):
            if size is None:
                size = rgb.shape[:2]
            elif rgb.shape[:2] != size:
                raise InputError(
                    source.path,
                    None,
                    f"frame {number} is {rgb.shape[1]}x"
                    f"{rgb.shape[0]}, the first was {size[1]}x{size[0]}",
                )
            yield number, rgb

    with FaceDetector(video=source.kind == "video", hands=opt.max_hand_cover < 1) as detect:
        for number, found in detect.stream(frames()):
            multi += found.n_faces > 1
            if found.landmarks is None:
                dropped.append({"frame": number, "reason": "no face found"})
            elif found.hand_cover > opt.max_hand_cover:
                dropped.append(
                    {
                        "frame": number,
                        "reason": f"a hand covers {found.hand_cover:.0%} of the face's landmarks",
                    }
                )
            else:
                numbers.append(number)
                landmarks.append(found.landmarks)
                masks.append(_Deflated(np.round(found.mask * 255).astype(np.uint8)))
            say(event="step", stage="detect", step=len(numbers) + len(dropped), total=chosen)
    times["detect"] = watch.seconds
    n_read = len(numbers) + len(dropped)
    if multi:
        warn_input(
            source.path,
            None,
            f"{multi} frames show more than one face; the largest face of each frame was tracked",
        )
    if len(numbers) < MIN_FRAMES:
        raise InputError(
            source.path,
            None,
            f"a face was found in {len(numbers)} of "
            f"{len(numbers) + len(dropped)} frames; tracking needs at least "
            f"{MIN_FRAMES}",
        )
    landmarks = np.array(landmarks)
    numbers = np.array(numbers)

    watch = Stopwatch()
    fit = fit_landmarks(
        model,
        embedding,
        landmarks,
        numbers,
        source.fps,
        size,
        FitOptions(focal=opt.focal),
        progress=lambda d, n, e: say(event="step", stage="fit", step=d, total=n),
    )
    times["fit"] = watch.seconds
    limit = max(OUTLIER_RATIO * np.median(fit.residual_px), OUTLIER_MIN_PX)
    keep = fit.residual_px <= limit
    for number, r in zip(numbers[~keep], fit.residual_px[~keep], strict=True):
        dropped.append(
            {
                "frame": int(number),
                "reason": f"landmark fit residual {r:.1f} px "
                f"(limit {limit:.1f} px): face occluded or mis-detected",
            }
        )
    if keep.sum() < MIN_FRAMES:
        raise InputError(source.path, None, f"only {keep.sum()} frames fit the face model")
    if dropped:
        warn_input(source.path, None, f"{len(dropped)} frames dropped (listed in the report)")

    x0, y0, side = _square_crop(landmarks[keep], size)
    kept = np.flatnonzero(keep)
    n = len(kept)
    fit = fit.select(kept)
    position = {int(numbers[i]): j for j, i in enumerate(kept)}
    out_size = (opt.size, opt.size)
    scale = opt.size / side
    small = min(opt.photometric.size, opt.size) if opt.photometric else 0
    with staged_folder(out) as stage:
        watch = Stopwatch()
        images, image_masks = [], []
        for number, rgb in source.frames(total, stride):
            j = position.get(number)
            if j is None:
                continue
            crop = rgb[y0 : y0 + side, x0 : x0 + side]
            mask = masks[kept[j]].array()[y0 : y0 + side, x0 : x0 + side].astype(np.float32) / 255
            frame = np.round(np.clip(resize(crop, out_size), 0, 255)).astype(np.uint8)
            mask = resize(mask, out_size)
            write_frame(stage, number, frame)
            write_mask(stage / PERSON_MASKS_DIR, number, mask)
            if small:
                images.append(
                    np.round(np.clip(resize(crop, (small, small)), 0, 255)).astype(np.uint8)
                )
                image_masks.append(resize(mask, (small, small)))
            say(event="step", stage="write", step=j + 1, total=n)
        times["write"] = watch.seconds
        photometric = None
        if small:
            watch = Stopwatch()
            images, image_masks = np.array(images), np.array(image_masks)  # the lists go
            clip = ClipFit(
                model,
                embedding,
                landmarks[kept],
                numbers[kept],
                source.fps,
                size,
                FitOptions(focal=fit.focal),  # the focal length as the landmarks left it
                init=fit.codes,
                static_offset=opt.static_offset,
            )
            photometric = refine_photometric(
                clip,
                images,
                image_masks,
                (x0, y0, side),
                opt.photometric,
                progress=lambda d, t, e: say(event="step", stage="refine", step=d, total=t),
            )
            times["refine"] = watch.seconds
            fit = clip.result(fit.seconds + watch.seconds)
        K = crop_intrinsics(fit.K, (x0, y0, side), opt.size)
        watch = Stopwatch()  # the head-and-neck masks follow the final fit
        regions = head_and_neck_masks(model, fit.codes, K, fit.w2c, out_size)
        for j, (number, inside) in enumerate(zip(numbers[kept], regions, strict=True)):
            person = read_mask(stage / PERSON_MASKS_DIR / frame_name(int(number)))
            write_mask(stage / MASKS_DIR, int(number), person * inside)
            write_mask(stage / REGIONS_DIR, int(number), inside)
            say(event="step", stage="masks", step=j + 1, total=n)
        times["masks"] = watch.seconds
        seq = fitted_sequence(
            fit.codes,
            numbers[kept],
            source.fps,
            str(source.path),
            K=np.tile(K, (n, 1, 1)),
            w2c=np.tile(fit.w2c, (n, 1, 1)),
            image_size=out_size,
        )
        write_canonical(seq, stage / TRACKING_FILE)
        report = _report(
            source,
            opt,
            n_read,
            numbers[kept],
            landmarks[kept],
            dropped,
            fit,
            scale,
            (x0, y0, side),
            times,
            multi,
            photometric,
            stride,
        )
        write_report(stage, report)
    return report


def frame_stride(frames: int, budget: int | None) -> int:
    """k: every k-th of a clip's `frames` is tracked, the fewest that keep to `budget`."""
    if budget is not None and budget < MIN_FRAMES:
        raise InputError(None, "frame_budget", f"{budget} frames: tracking needs {MIN_FRAMES}")
    return 1 if budget is None else max(math.ceil(frames / budget), 1)


def _offset_mm(offset) -> dict | None:
    if offset is None:
        return None
    length = np.linalg.norm(offset, axis=1) * 1000
    return {"median": round(float(np.median(length)), 3), "max": round(float(length.max()), 3)}


def jitter_px(points: np.ndarray, numbers: np.ndarray, stride: int = 1) -> float:
    """Median second difference of landmark tracks (T,L,2) over runs of frames `stride` apart
    (consecutive ones of those tracked): how far points jump beyond constant velocity."""
    run = (np.diff(numbers[:-1]) == stride) & (np.diff(numbers[1:]) == stride)
    if not run.any():
        return float("nan")
    second = points[2:] - 2 * points[1:-1] + points[:-2]
    return float(np.median(np.linalg.norm(second[run], axis=-1)))


def _report(
    source,
    opt,
    n_read,
    numbers,
    landmarks,
    dropped,
    fit,
    scale,
    crop,
    times,
    multi,
    photometric,
    stride,
) -> dict:
    """The tracking report of the kept frames (`numbers`, `landmarks`, `fit` are theirs)."""
    good = fit.landmark_residual_px * scale  # at the output size
    residual = fit.residual_px * scale
    rounded = {
        k: round(v, 3)
        for k, v in (
            ("median", np.median(residual)),
            ("p95", np.percentile(residual, 95)),
            ("all_landmarks_median", np.median(good)),
        )
    }
    return {
        "source": str(source.path),
        "frames_read": int(n_read),
        "frame_stride": stride,  # every k-th frame of the clip was read
        "frames_kept": int(len(numbers)),
        "dropped": sorted(dropped, key=lambda d: d["frame"]),
        "frames_with_several_faces": int(multi),
        "frames_with_a_hand_over_the_face": sum("hand covers" in d["reason"] for d in dropped),
        "output_size": opt.size,
        "crop_xywh": [crop[0], crop[1], crop[2], crop[2]],
        "focal_px_source": round(fit.focal, 2),
        "focal_given": opt.focal is not None,
        "model": opt.flame or "built-in",
        "residual_px": rounded,
        "jitter_px": {
            "fitted": round(jitter_px(fit.projected * scale, numbers, stride), 3),
            "detected": round(jitter_px(landmarks * scale, numbers, stride), 3),
        },
        "photometric": None if photometric is None else photometric.as_dict(),
        "static_offset_mm": _offset_mm(fit.codes.get("static_offset")),
        "seconds": {k: round(v, 2) for k, v in times.items()},
        "seconds_per_frame": round(sum(times.values()) / max(n_read, 1), 3),
    }
