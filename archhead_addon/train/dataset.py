"""Training frames from a folder: images, masks, the parts mask B, cameras and FLAME codes.

numpy only (no torch), so tests and tools use it without the training stack.

Folder layout (DATA):

    DATA/frames/<n>.png|.jpg|.jpeg|.exr   the video frames, numbered (00000.png, img_12.jpg)
    DATA/masks/<n>.<ext>                  optional: foreground alpha, the frames' numbers
    DATA/masks_person/<n>.<ext>           optional: the whole person (mask="person"); the
                                          tracker's masks/ keep head and neck only
    DATA/regions/<n>.<ext>                optional: the tracker's head-and-neck region, which
                                          cuts its masks/ (`region` below)
    DATA/parts/<n>.<ext>                  optional: the eye/mouth mask B, the frames' numbers
    DATA/tracking.npz                     the tracked sequence (or pass `tracking=` a file or
                                          folder in any format `read_sequence` reads)

- Frames and tracking match by order: the i-th frame file (by number) is the i-th tracked
  frame. Their counts must agree; when frames are fewer, the error names the missing frame
  numbers. Numbers that step unlike the tracking's frame ids give a warning.
- Every frame must have the same size, and so must its mask and parts files; the tracking's
  `image_size` (when stored) must have the frames' aspect ratio. The tracking must have a
  camera (K and w2c).
- Images are resized to `resolution`: an int is the longer side (the aspect ratio kept, the
  other side rounded), a pair is (H, W). Shrinking averages the area each output pixel
  covers, enlarging is bilinear; pixel centres sit at +0.5 on both sides, so
  K' = diag(s_x, s_y, 1) K with s_x = W' / W_k and s_y = H' / H_k, where (H_k, W_k) is the
  size K was tracked at (`image_size`, else the frames' size).
- Background: where a mask exists (a masks/ file, or masks_person/ with mask="person", else
  the frame's own alpha channel), the frame is composited onto `background` (RGB in [0,1],
  white by default) at full size before resizing: image = mask * frame + (1 - mask) *
  background. The renderer in training must clear to the same colour. Without masks,
  frames are used as they are and the mask is all ones.
- B: the parts/ files when given (resized, soft at the edges); else the model's eye and
  mouth labels rasterized with occlusion in each frame (`parts_mask`). `head`: the tracked
  head without its neck (`flame.regions`), rasterized the same way, where the evaluation
  scores the face alone. `region`: with the head-and-neck masks, where the tracker's mask may
  hold anything (`track.head_mask.region`, from the tracked mesh alone, without the person's
  segmentation): the regions/ files, resized; in a tracked folder without them (tracked
  before the tracker wrote them; it holds masks_person/) drawn from the tracking at the
  frames' size as the tracker drew it, then resized; all ones with the whole person's masks
  or with masks not the tracker's. A run with `cut` "region" cuts its renders to it, as the
  mask cuts the truth.
- Split (paper 4.1): the first 90 % of frames train, the last 10 % test (at least one each
  when there are two or more frames); `split="all"` gives every frame. With
  `holdout="interleaved"` every tenth frame tests instead (frames 4, 14, ...): test poses
  and expressions then lie among the training ones, which tells how well an avatar
  generalises within what it saw from how well it extrapolates to the clip's end.
  `frames=N` keeps N frames of the split, evenly spread (the first and last among them):
  the quality ladder fits one or ten frames alone, and scores those same frames.

`FrameDataset(...)[i]` is a dict of float32 arrays: `image` (H,W,3) in [0,1], `mask` (H,W),
`parts` (H,W), `head` (H,W), `region` (H,W), `K` (3,3), `w2c` (4,4), `codes` {shape, expr,
jaw, neck, eyes, rotation, translation} (1-D each, fitted to the model's widths), plus
`frame_id` and `index` (the frame's position in the whole sequence). With `cache=True`
(default) frames are decoded once and kept (about 28 bytes per pixel); the arrays are then
shared, so do not modify them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..flame.lbs import forward
from ..flame.model import FlameModel
from ..io.errors import InputError, warn_input
from ..sequences import Sequence, read_sequence
from ..sequences.common import numbered_files
from ..sequences.validation import check_trainable
from ..track.head_mask import region
from .config import HOLDOUTS, MASKS
from .images import IMAGE_SUFFIXES, image_size, read_image, read_mask, resize
from .parts_mask import surface_regions

FRAMES_DIR, MASKS_DIR, PARTS_DIR, TRACKING_FILE = "frames", "masks", "parts", "tracking.npz"
PERSON_MASKS_DIR, REGIONS_DIR = "masks_person", "regions"
MASK_FOLDERS = dict(zip(MASKS, (MASKS_DIR, PERSON_MASKS_DIR), strict=True))  # `mask` -> folder
SPLITS = ("train", "test", "all")
CODES = ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")


def split_point(n_frames: int) -> int:
    """How many leading frames train: 90 % rounded down, which leaves at least one test
    frame and, from two frames on, at least one training frame. A single frame trains."""
    return 9 * n_frames // 10 if n_frames > 1 else n_frames


def split_indices(n_frames: int, holdout: str = "last") -> tuple[list[int], list[int]]:
    """(train, test) frame positions for `holdout` (HOLDOUTS)."""
    if holdout not in HOLDOUTS:
        raise ValueError(f"holdout must be one of {HOLDOUTS}, got {holdout!r}")
    if holdout == "last" or n_frames < 5:
        n_train = split_point(n_frames)
        return list(range(n_train)), list(range(n_train, n_frames))
    test = list(range(4, n_frames, 10))
    return sorted(set(range(n_frames)) - set(test)), test


def target_size(resolution, source: tuple[int, int]) -> tuple[int, int]:
    """(H', W') for `resolution` (int: the longer side; or (H, W)) and a source (H, W)."""
    if isinstance(resolution, int | np.integer):
        size = (resolution,) * 2
        if resolution > 0:
            size = tuple(max(round(n * resolution / max(source)), 1) for n in source)
    else:
        size = tuple(int(n) for n in resolution)
    if len(size) != 2 or min(size) < 1:
        raise ValueError(f"resolution must be a positive int or (H, W), got {resolution!r}")
    return size


def numbered_images(folder: Path) -> list[tuple[int, Path]]:
    """The folder's numbered images, one suffix only (see `numbered_files` for the rules)."""
    if not folder.is_dir():
        raise InputError(folder, None, "folder not found")
    suffixes = sorted(
        {p.suffix for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES}
    )
    if not suffixes:
        raise InputError(folder, None, "no PNG, JPG or EXR images in this folder")
    if len(suffixes) > 1:
        raise InputError(
            folder, None, f"mixed image types ({', '.join(suffixes)}); use one per folder"
        )
    return numbered_files(folder, suffixes[0])


def _companions(folder: Path, frames: list[tuple[int, Path]], what: str) -> list[Path] | None:
    """The masks/ or parts/ file of every frame (None when the folder does not exist)."""
    if not folder.exists():
        return None
    by_number = dict(numbered_images(folder))
    missing = [path.name for n, path in frames if n not in by_number]
    if missing:
        shown = ", ".join(missing[:8]) + (
            f" (and {len(missing) - 8} more)" if len(missing) > 8 else ""
        )
        raise InputError(
            folder, None, f"no {what} for frames {shown}: every frame needs one (same number)"
        )
    return [by_number[n] for n, _ in frames]


def _match_tracking(frames: list[tuple[int, Path]], seq: Sequence, folder: Path) -> None:
    numbers = np.array([n for n, _ in frames])
    ids = seq.frame_ids
    if len(numbers) < len(ids):
        expected = ids - ids[0] + numbers[0]
        missing = np.setdiff1d(expected, numbers)
        detail = (
            (
                f"; missing frame numbers {', '.join(map(str, missing[:12]))}"
                + (" ..." if len(missing) > 12 else "")
            )
            if len(missing)
            else ""
        )
        raise InputError(
            folder,
            None,
            f"{len(numbers)} frames for {len(ids)} tracked frames ({seq.source}){detail}",
        )
    if len(numbers) > len(ids):
        raise InputError(
            folder,
            None,
            f"{len(numbers)} frames but the tracking "
            f"({seq.source}) has only {len(ids)}: frames "
            f"{frames[len(ids)][1].name} and after have no tracking",
        )
    if not np.array_equal(np.diff(numbers), np.diff(ids)):
        warn_input(
            folder,
            None,
            "frame numbers do not step like the tracking's frame ids; "
            "frames are matched to tracked frames by order",
        )


def _one_size(paths: list[Path], want: tuple[int, int] | None = None) -> tuple[int, int]:
    """The (H, W) all `paths` share: `want` when given, else the first file's."""
    reference = want
    for path in paths:
        size = image_size(path)
        if reference is not None and size != reference:
            other = "the frames are" if want is not None else f"{paths[0].name} is"
            raise InputError(
                path,
                None,
                f"{size[1]}x{size[0]} pixels, but {other} "
                f"{reference[1]}x{reference[0]}: sizes must match",
            )
        reference = reference or size
    return reference


class FrameDataset:
    """Frames of one split (module docstring); `len()` and `[i]` give per-frame dicts."""

    def __init__(
        self,
        data_dir,
        resolution,
        model: FlameModel,
        *,
        split: str = "train",
        holdout: str = "last",
        mask: str = "head",
        frames: int | None = None,
        tracking=None,
        background=(1.0, 1.0, 1.0),
        cache: bool = True,
    ):
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        self.root = Path(data_dir)
        if not self.root.is_dir():
            raise InputError(self.root, None, "data folder not found")
        self.model = model
        self.background = np.asarray(background, dtype=np.float32)
        if (
            self.background.shape != (3,)
            or not ((self.background >= 0) & (self.background <= 1)).all()
        ):
            raise ValueError(f"background must be an RGB triple in [0, 1], got {background!r}")
        self.sequence = self._read_tracking(tracking).fit_to_model(model)
        numbered = numbered_images(self.root / FRAMES_DIR)
        _match_tracking(numbered, self.sequence, self.root / FRAMES_DIR)
        self.frame_paths = [p for _, p in numbered]
        if mask not in MASK_FOLDERS:
            raise ValueError(f"mask must be one of {tuple(MASK_FOLDERS)}, got {mask!r}")
        self.mask_paths = _companions(self.root / MASK_FOLDERS[mask], numbered, "mask")
        if mask == "person" and self.mask_paths is None:
            raise InputError(
                self.root,
                PERSON_MASKS_DIR,
                "no whole-person masks here (the tracker writes them); track the video again "
                "or train with the head-and-neck masks",
            )
        self.parts_paths = _companions(self.root / PARTS_DIR, numbered, "parts mask")
        if self.parts_paths is None and model.vertex_parts is None:
            warn_input(
                model.source,
                "vertex_parts",
                f"no eye/mouth labels in the model and no "
                f"{PARTS_DIR}/ masks in {self.root}: the parts mask B is empty",
            )
        # the region cutting the head-and-neck masks, as the tracker wrote it
        head_masks = mask == "head" and self.mask_paths is not None
        self.region_paths = (
            _companions(self.root / REGIONS_DIR, numbered, "region") if head_masks else None
        )
        source = _one_size(self.frame_paths)
        for companions in (self.mask_paths, self.parts_paths, self.region_paths):
            if companions is not None:
                _one_size(companions, want=source)
        self.source_size = source
        self.size = target_size(resolution, source)
        self.K = self._scaled_intrinsics(source)
        train, test = split_indices(len(numbered), holdout)
        self.indices = {"train": train, "test": test, "all": list(range(len(numbered)))}[split]
        if len(self.indices) == 0:
            raise InputError(
                self.root,
                None,
                f"the '{split}' split of {len(numbered)} frame(s) "
                "is empty: a train/test split needs at least two frames",
            )
        if frames is not None:
            if frames < 1:
                raise ValueError(f"frames must be >= 1, got {frames}")
            spread = np.linspace(0, len(self.indices) - 1, min(frames, len(self.indices)))
            self.indices = [self.indices[int(i)] for i in np.unique(spread.round())]
        self.split, self.holdout, self.mask = split, holdout, mask
        # Whether the truth is cut to the tracking's head-and-neck region, so that `region`
        # is more than all ones: the tracker's masks/ (its folders hold regions/, or in older
        # ones masks_person/, beside them; other masks may keep anything).
        self.cuts_to_region = head_masks and (
            self.region_paths is not None or (self.root / PERSON_MASKS_DIR).is_dir()
        )
        # without regions/ the region is drawn with the cameras at the frames' own size;
        # uncut, one shared array
        drawn = self.cuts_to_region and self.region_paths is None
        self._source_K = self._scaled_intrinsics(source, source) if drawn else None
        self._uncut = np.ones(self.size, np.float32)
        self._cache: dict[int, dict] | None = {} if cache else None

    def _read_tracking(self, tracking) -> Sequence:
        path = Path(tracking) if tracking is not None else self.root / TRACKING_FILE
        if tracking is None and not path.exists():
            raise InputError(
                self.root,
                None,
                f"no {TRACKING_FILE} in this folder: pass the "
                "tracked sequence (any supported format) as tracking=PATH",
            )
        seq = read_sequence(path)
        if not seq.has_camera:
            raise InputError(
                path, "K", "the tracking has no camera (K and w2c); training needs one per frame"
            )
        check_trainable(seq)  # codes read with a warning, that training would overflow on
        return seq

    def _scaled_intrinsics(self, source: tuple[int, int], size=None) -> np.ndarray:
        """The tracking's K for frames of `source` size resized to `size` (the target)."""
        tracked = self.sequence.image_size or source
        h, w = source
        if abs(tracked[0] * w / tracked[1] - h) > 1.0:
            raise InputError(
                self.root / FRAMES_DIR,
                None,
                f"frames are {w}x{h} pixels but the "
                f"tracking's camera is for {tracked[1]}x{tracked[0]}: the aspect "
                "ratios differ",
            )
        size = self.size if size is None else size
        scale = np.diag([size[1] / tracked[1], size[0] / tracked[0], 1.0])
        return scale @ self.sequence.K

    @property
    def frame_ids(self) -> np.ndarray:
        return self.sequence.frame_ids[list(self.indices)]

    @property
    def has_masks(self) -> bool:
        return self.mask_paths is not None

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, i: int) -> dict:
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} of a {len(self)}-frame split")
        t = self.indices[i]
        if self._cache is not None and t in self._cache:
            return self._cache[t]
        item = self._load(t)
        if self._cache is not None:
            self._cache[t] = item
        return item

    def _region(self, t: int, vertices: np.ndarray) -> np.ndarray:
        """The tracker's head-and-neck region of frame t at the frames' own size (its file, or
        drawn as the tracker drew it, so that it holds every pixel its mask keeps), resized as
        the masks are: each pixel the share of it inside, as the truth's mask is the share
        inside the person and the region. A render cut so is cut as the truth was."""
        if self.region_paths is not None:
            return resize(read_mask(self.region_paths[t]), self.size)
        found = surface_regions(
            self.model, vertices, self._source_K[t], self.sequence.w2c[t], self.source_size
        )
        return resize(region(found.head, found.mesh).astype(np.float32), self.size)

    def _load(self, t: int) -> dict:
        seq = self.sequence
        rgb, alpha = read_image(self.frame_paths[t])
        mask = read_mask(self.mask_paths[t]) if self.has_masks else alpha
        if mask is not None:
            rgb = mask[..., None] * rgb + (1 - mask[..., None]) * self.background
        mask = np.ones(self.source_size, np.float32) if mask is None else mask
        codes = {k: getattr(seq, k)[t] for k in CODES}
        vertices = forward(self.model, static_offset=seq.static_offset, **codes)[0]
        regions = surface_regions(self.model, vertices, self.K[t], seq.w2c[t], self.size)
        parts = regions.parts
        cut = self._region(t, vertices) if self.cuts_to_region else self._uncut
        if self.parts_paths is not None:
            parts = resize(read_mask(self.parts_paths[t]), self.size)
        return {
            "image": np.clip(resize(rgb.astype(np.float32), self.size), 0, 1),
            "mask": np.clip(resize(mask.astype(np.float32), self.size), 0, 1),
            "parts": parts.astype(np.float32),
            "head": regions.head,
            "region": cut,
            "face": regions.face > 0.5,  # bool: a cached training set holds one per frame
            "K": self.K[t].astype(np.float32),
            "w2c": seq.w2c[t].astype(np.float32),
            "codes": {k: v.astype(np.float32) for k, v in codes.items()},
            "frame_id": int(seq.frame_ids[t]),
            "index": t,
        }
