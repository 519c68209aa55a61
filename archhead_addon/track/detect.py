"""MediaPipe Face Mesh landmarks (478, iris included) and selfie segmentation masks.

Only the legacy `solutions` API of `mediapipe==0.10.21` is used: its `.tflite` models ship
inside the wheel, so nothing is downloaded (later versions fetch their models at run time,
which fails offline). The check below refuses to start rather than let a download happen.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np

N_LANDMARKS = 478
MEDIAPIPE_VERSION = "0.10.21"
_MODELS = (
    "modules/face_landmark/face_landmark_with_attention.tflite",
    "modules/face_detection/face_detection_short_range.tflite",
    "modules/selfie_segmentation/selfie_segmentation.tflite",
)


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


class FaceDetector:
    """Landmarks of the largest face per frame; `video=True` tracks between frames."""

    def __init__(self, video: bool = True, max_faces: int = 4, masks: bool = True):
        _check_mediapipe()
        from mediapipe.python.solutions import face_mesh, selfie_segmentation

        self._mesh = face_mesh.FaceMesh(
            static_image_mode=not video,
            max_num_faces=max_faces,
            refine_landmarks=True,
            min_detection_confidence=0.5,
            min_tracking_confidence=0.5,
        )
        self._segment = selfie_segmentation.SelfieSegmentation(model_selection=0) if masks else None

    def __call__(self, rgb: np.ndarray) -> Detection:
        rgb = np.ascontiguousarray(rgb)
        height, width = rgb.shape[:2]
        result = self._mesh.process(rgb)
        faces = result.multi_face_landmarks or []
        landmarks = None
        if faces:
            # MediaPipe's normalised coordinates put pixel centres at +0.5 (x * width).
            all_faces = [
                np.array([(p.x * width, p.y * height) for p in face.landmark]) for face in faces
            ]
            landmarks = max(all_faces, key=lambda lm: np.ptp(lm[:, 0]) * np.ptp(lm[:, 1]))
        mask = None
        if self._segment is not None:
            mask = self._segment.process(rgb).segmentation_mask.astype(np.float32)
        return Detection(landmarks, len(faces), mask)

    def close(self) -> None:
        self._mesh.close()
        if self._segment is not None:
            self._segment.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
