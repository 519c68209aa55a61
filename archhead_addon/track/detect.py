"""MediaPipe Face Mesh landmarks (478, iris included), selfie segmentation masks, and the
hands that cover the face.

Only the legacy `solutions` API of `mediapipe==0.10.21` is used: its `.tflite` models ship
inside the wheel, so nothing is downloaded (later versions fetch their models at run time,
which fails offline). The check below refuses to start rather than let a download happen.
"""

from __future__ import annotations

import importlib.util
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

N_LANDMARKS = 478
MEDIAPIPE_VERSION = "0.10.21"
_MODELS = (
    "modules/face_landmark/face_landmark_with_attention.tflite",
    "modules/face_detection/face_detection_short_range.tflite",
    "modules/selfie_segmentation/selfie_segmentation.tflite",
    "modules/palm_detection/palm_detection_full.tflite",
    "modules/hand_landmark/hand_landmark_full.tflite",
)
# A face landmark lies under a hand when it is inside the hand's outline (the convex hull of
# its 21 joints) grown by this fraction of the hand's size: joints sit on the fingers' centre
# lines, so the bare hull misses the fingers' own width.
HAND_MARGIN = 0.12
# A frame with more of its face landmarks under a hand than this is dropped: Face Mesh keeps
# plausible points under a hand, but the frame would teach the avatar the hand as skin.
MAX_HAND_COVER = 0.03


class TrackerUnavailable(RuntimeError):
    """The landmark models cannot run here (mediapipe missing, or the wrong version)."""


def _check_mediapipe() -> None:
    spec = importlib.util.find_spec("mediapipe")
    if spec is None or spec.origin is None:
        raise TrackerUnavailable(
            f"the tracker needs mediapipe=={MEDIAPIPE_VERSION} (installed by `make setup`)"
        )
    root = Path(spec.origin).parent
    missing = [m for m in _MODELS if not (root / m).is_file()]
    if missing:
        raise TrackerUnavailable(
            f"mediapipe at {root} lacks its bundled models ({missing[0]}); "
            f"install mediapipe=={MEDIAPIPE_VERSION}, whose wheel carries "
            "them (later versions download models at run time)"
        )


@dataclass
class Detection:
    landmarks: np.ndarray | None  # (478,2) pixels, centres at +0.5; None when no face
    n_faces: int
    mask: np.ndarray | None  # (H,W) float32 foreground probability, when asked for
    hand_cover: float = 0.0  # fraction of the face's landmarks under a detected hand


def hand_cover(face: np.ndarray, hands: list[np.ndarray]) -> float:
    """Fraction of the face landmarks (L,2) that lie under any of `hands` ((21,2) each)."""
    import cv2

    covered = np.zeros(len(face), dtype=bool)
    for hand in hands:
        hull = cv2.convexHull(hand.astype(np.float32))
        margin = HAND_MARGIN * float(np.linalg.norm(np.ptp(hand, axis=0)))
        for i in np.flatnonzero(~covered):
            pt = (float(face[i, 0]), float(face[i, 1]))
            covered[i] = cv2.pointPolygonTest(hull, pt, True) > -margin
    return float(covered.mean())


class FaceDetector:
    """Landmarks of the largest face per frame; `video=True` tracks between frames.

    The models (Face Mesh, the segmentation, the hands) each run on a thread of their own,
    frames in order, a few frames ahead of the caller (`stream`): MediaPipe releases the GIL
    while a model runs, so the three share the cores where one after the other they took
    one (docs/tracking.md, "the detectors side by side")."""

    AHEAD = 4  # frames in flight: each holds its RGB frame and its models' outputs

    def __init__(
        self, video: bool = True, max_faces: int = 4, masks: bool = True, hands: bool = True
    ):
        _check_mediapipe()
        from mediapipe.python.solutions import face_mesh, selfie_segmentation
        from mediapipe.python.solutions import hands as hand_landmarks

        self._models = {
            "mesh": face_mesh.FaceMesh(
                static_image_mode=not video,
                max_num_faces=max_faces,
                refine_landmarks=True,
                min_detection_confidence=0.5,
                min_tracking_confidence=0.5,
            )
        }
        if masks:
            self._models["mask"] = selfie_segmentation.SelfieSegmentation(model_selection=0)
        if hands:
            self._models["hands"] = hand_landmarks.Hands(
                static_image_mode=not video,
                max_num_hands=2,
                model_complexity=1,
                min_detection_confidence=0.5,
                min_tracking_confidence=0.5,
            )
        # one thread per model: a model's frames go through it in order, as video mode needs
        self._threads = {
            name: ThreadPoolExecutor(1, thread_name_prefix=f"archhead-{name}")
            for name in self._models
        }

    def __call__(self, rgb: np.ndarray) -> Detection:
        return next(self.stream([(None, rgb)]))[1]

    def stream(self, frames: Iterable[tuple[Any, np.ndarray]]) -> Iterator[tuple[Any, Detection]]:
        """(key, detection) for each (key, RGB uint8 frame) of `frames`, in order."""
        pending = deque()
        for key, rgb in frames:
            rgb = np.ascontiguousarray(rgb)
            outputs = {
                name: self._threads[name].submit(_OUTPUTS[name], model, rgb)
                for name, model in self._models.items()
            }
            pending.append((key, outputs))
            if len(pending) > self.AHEAD:
                key, outputs = pending.popleft()
                yield key, _detection(outputs)
        while pending:
            key, outputs = pending.popleft()
            yield key, _detection(outputs)

    def close(self) -> None:
        for thread in self._threads.values():  # a model's last frame ends before it closes
            thread.shutdown(wait=True, cancel_futures=True)
        for model in self._models.values():
            model.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _faces(model, rgb: np.ndarray) -> list[np.ndarray]:
    """Every face's landmarks (478,2) in pixels."""
    return [_pixels(face, rgb) for face in model.process(rgb).multi_face_landmarks or []]


def _mask(model, rgb: np.ndarray) -> np.ndarray:
    return model.process(rgb).segmentation_mask.astype(np.float32)  # a copy of its buffer


def _hands(model, rgb: np.ndarray) -> list[np.ndarray]:
    """Every hand's joints (21,2) in pixels."""
    return [_pixels(hand, rgb) for hand in model.process(rgb).multi_hand_landmarks or []]


def _pixels(points, rgb: np.ndarray) -> np.ndarray:
    """MediaPipe's normalised landmarks in pixels: its coordinates put pixel centres at +0.5
    (x * width)."""
    height, width = rgb.shape[:2]
    return np.array([(p.x * width, p.y * height) for p in points.landmark])


_OUTPUTS = {"mesh": _faces, "mask": _mask, "hands": _hands}


def _detection(futures: dict) -> Detection:
    """A frame's Detection from its models' outputs (raises what a model raised)."""
    faces = futures["mesh"].result()
    landmarks = max(faces, key=lambda lm: np.ptp(lm[:, 0]) * np.ptp(lm[:, 1])) if faces else None
    mask = futures["mask"].result() if "mask" in futures else None
    hands = futures["hands"].result() if "hands" in futures else []
    cover = 0.0 if landmarks is None else hand_cover(landmarks, hands)
    return Detection(landmarks, len(faces), mask, cover)
