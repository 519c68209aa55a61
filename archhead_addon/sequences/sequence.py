"""The canonical tracked sequence every reader produces.

Per frame (T frames): FLAME codes and pose in FLAME space (metres, y up), all float64,
rotations as axis-angle vectors in radians:

- `shape` (T,S) identity; formats that store one identity have it repeated on every frame;
- `expr` (T,E) expression; `jaw`, `neck`, `rotation` (global, about the root joint) (T,3);
- `eyes` (T,6) left eye then right eye (FLAME joints 3 and 4); `translation` (T,3) metres;
- `eyelids` (T,2) or None (metrical-tracker's eyelid blendshape weights, left then right);
- camera, or None for both: `K` (T,3,3) intrinsics in pixels, pixel centres at +0.5, and
  `w2c` (T,4,4) OpenCV world-to-camera (x right, y down, z forward); `image_size` (H,W);
- `frame_ids` (T,) int64, strictly increasing; `fps`.

Once per sequence: `static_offset` (V,3) per-vertex offsets added to the template (VHAP) or
None; `source` (the path read) and `format` (the reader's name).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from ..io.errors import InputError, warn_input
from .validation import check_frame_count, check_values

DEFAULT_FPS = 25.0
"""Frame rate assumed (with a warning) for formats that do not store one."""

# Per-frame float fields and their width after the frame axis.
PER_FRAME = {
    "shape": None,
    "expr": None,
    "jaw": (3,),
    "neck": (3,),
    "eyes": (6,),
    "rotation": (3,),
    "translation": (3,),
    "eyelids": (2,),
    "K": (3, 3),
    "w2c": (4, 4),
}
OPTIONAL = ("eyelids", "K", "w2c", "static_offset")


@dataclass(frozen=True, eq=False)
class Sequence:
    shape: np.ndarray
    expr: np.ndarray
    jaw: np.ndarray
    neck: np.ndarray
    eyes: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    fps: float
    frame_ids: np.ndarray
    source: str
    format: str
    K: np.ndarray | None = None
    w2c: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    static_offset: np.ndarray | None = None
    eyelids: np.ndarray | None = None

    def __post_init__(self):
        for name in (*PER_FRAME, "static_offset"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, np.asarray(value, dtype=np.float64))
        object.__setattr__(self, "frame_ids", np.asarray(self.frame_ids, dtype=np.int64))
        object.__setattr__(self, "fps", float(self.fps))
        object.__setattr__(self, "source", str(self.source))
        if self.image_size is not None:
            object.__setattr__(self, "image_size", tuple(int(n) for n in self.image_size))

    def __len__(self) -> int:
        return len(self.expr)

    @property
    def has_camera(self) -> bool:
        return self.K is not None

    def validate(self) -> Sequence:
        """Check shapes and values; raise InputError naming the key (and frame) at fault."""
        if self.expr.ndim != 2:
            raise InputError(self.source, "expr", f"expected shape (T, E), found {self.expr.shape}")
        n = len(self.expr)
        if n == 0:
            raise InputError(self.source, "expr", "the sequence has no frames")
        check_frame_count(n, self.source)
        if self.frame_ids.shape != (n,):
            raise InputError(
                self.source, "frame_ids", f"expected shape ({n},), found {self.frame_ids.shape}"
            )
        if n > 1 and not (np.diff(self.frame_ids) > 0).all():
            raise InputError(self.source, "frame_ids", "frame ids are not strictly increasing")
        if (self.K is None) != (self.w2c is None):
            raise InputError(
                self.source,
                "K" if self.K is None else "w2c",
                "intrinsics and extrinsics must be given together",
            )
        if self.K is not None and self.image_size is None:
            raise InputError(
                self.source,
                "image_size",
                "missing: a sequence with cameras (K, w2c) needs the image size (H, W) "
                "its intrinsics are in",
            )
        for name, width in PER_FRAME.items():
            value = getattr(self, name)
            if value is None:
                continue
            if (
                value.ndim != 1 + (len(width) if width else 1)
                or len(value) != n
                or (width and value.shape[1:] != width)
            ):
                want = f"({n}, {', '.join(map(str, width))})" if width else f"({n}, N)"
                raise InputError(self.source, name, f"expected shape {want}, found {value.shape}")
            bad = ~np.isfinite(value.reshape(n, -1)).all(axis=1)
            if bad.any():
                t = int(np.argmax(bad))
                raise InputError(
                    self.source,
                    name,
                    f"NaN or Inf at frame index {t} (frame id {self.frame_ids[t]})",
                )
        self._validate_once_per_sequence()
        check_values(self)
        return self

    def _validate_once_per_sequence(self) -> None:
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise InputError(
                self.source, "fps", f"expected a positive frame rate, found {self.fps}"
            )
        if self.image_size is not None and (len(self.image_size) != 2 or min(self.image_size) <= 0):
            raise InputError(
                self.source, "image_size", f"expected (H, W) > 0, found {self.image_size}"
            )
        offset = self.static_offset
        if offset is not None:
            if offset.ndim != 2 or offset.shape[1] != 3:
                raise InputError(
                    self.source, "static_offset", f"expected shape (V, 3), found {offset.shape}"
                )
            bad = ~np.isfinite(offset).all(axis=1)
            if bad.any():
                raise InputError(
                    self.source,
                    "static_offset",
                    f"NaN or Inf at vertex index {int(np.argmax(bad))}",
                )

    def fit_to_model(self, model) -> Sequence:
        """A copy whose shape/expr widths (and static_offset rows) match `model`, with a
        warning that says what was padded with zeros or truncated."""
        shape = _fit_width(
            self.shape, model.n_shape, self.source, "shape", "identity shape coefficients"
        )
        expr = _fit_width(self.expr, model.n_expr, self.source, "expr", "expression coefficients")
        return replace(self, shape=shape, expr=expr, static_offset=self._fit_offset(model))

    def _fit_offset(self, model) -> np.ndarray | None:
        offset, n_verts = self.static_offset, model.n_verts
        if offset is None or len(offset) == n_verts:
            return offset
        if len(offset) < n_verts:  # the model appends vertices (teeth): they get no offset
            teeth = model.extras.get("teeth")
            if teeth is None or teeth["first_vertex"] != len(offset):  # not just the teeth
                warn_input(
                    self.source,
                    "static_offset",
                    f"{len(offset)} vertex offsets, the model "
                    f"has {n_verts} vertices: padded with {n_verts - len(offset)} zero rows",
                )
            return np.concatenate([offset, np.zeros((n_verts - len(offset), 3))])
        warn_input(
            self.source,
            "static_offset",
            f"{len(offset)} vertex offsets, more than the "
            f"model's {n_verts} vertices (another topology): offsets dropped",
        )
        return None

    def subset(self, start: int = 0, stop: int | None = None, stride: int = 1) -> Sequence:
        """Frames [start:stop:stride] (Python slice rules); an empty result is an error."""
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        frames = slice(start, stop, stride)
        if len(range(*frames.indices(len(self)))) == 0:
            raise InputError(
                self.source,
                None,
                f"frames [{start}:{stop}:{stride}] of a {len(self)}-frame sequence are empty",
            )
        changes = {
            name: getattr(self, name)[frames]
            for name in PER_FRAME
            if getattr(self, name) is not None
        }
        return replace(self, frame_ids=self.frame_ids[frames], **changes)

    def data_equal(self, other: Sequence) -> bool:
        """Same frames, codes and cameras (source and format may differ)."""
        for f in fields(self):
            if f.name in ("source", "format"):
                continue
            a, b = getattr(self, f.name), getattr(other, f.name)
            if (a is None) != (b is None):
                return False
            if isinstance(a, np.ndarray):
                if a.shape != b.shape or not np.array_equal(a, b):
                    return False
            elif a != b:
                return False
        return True


def _fit_width(codes: np.ndarray, width: int, source, key: str, what: str) -> np.ndarray:
    have = codes.shape[1]
    if have == width:
        return codes
    if have < width:
        warn_input(
            source, key, f"{have} {what}, the model has {width}: padded with {width - have} zeros"
        )
        return np.concatenate([codes, np.zeros((len(codes), width - have))], axis=1)
    warn_input(
        source,
        key,
        f"{have} {what}, the model has {width}: truncated, the last {have - width} dropped",
    )
    return codes[:, :width].copy()
