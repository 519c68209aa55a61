"""Training configuration: one JSON file (configs/*.json) read into `TrainConfig`.

    {"resolution": 256, "stage1_steps": 15000, "stage2_steps": 30000, "lods_per_step": 5,
     "lr": {"features": ..., "mapping": ..., "decoder": ...}, "lr_final_ratio": 0.1,
     "loss": {"parts": 20, "lpips": 0.05, ...}, "avatar": {"s_max": 256, ...}, ...}

Every key is optional; unknown keys are errors. "avatar" holds AvatarConfig fields (the
model's size: UV resolutions, feature-field levels, widths). torch-free, so the command line
reads it before torch loads.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

from ..avatar.config import AvatarConfig
from ..io.errors import InputError
from ..io.json_input import load_json
from ..io.schema import finite_real
from ..threads import thread_count
from .config_ranges import check_ranges

HOLDOUTS = ("last", "interleaved")  # which frames test (dataset.split_indices)
MASKS = ("head", "person")  # which masks cut the frames (dataset.MASK_FOLDERS)
CUTS = ("none", "region")  # what a run's renders are cut to before the loss and the scores
LPIPS_LEVELS = ("all", "one")  # which of a stage-2 step's renders the perceptual term sees

CONFIG_DIR = Path(__file__).parent / "configs"
PRESETS = ("cpu", "cpu_short", "gpu_paper", "demo")
# Where every training starts unless told otherwise: the command line and Blender's Train
# operator alike (the dataclass defaults below are not a preset of their own).
DEFAULT_PRESET = "cpu"
STAGE_STEPS = ("stage1_steps", "stage2_steps", "stage3_steps", "stage4_steps")
WHOLE_NUMBERS = (
    "resolution",
    "frames",
    "stage1_steps",
    "stage2_steps",
    "stage3_steps",
    "stage4_steps",
    "lods_per_step",
    "lpips_every",
    "checkpoint_every",
    "seed",
    "threads",
)


@dataclass(frozen=True)
class LossWeights:
    """The weights of eq. 6-7 (the paper's values) and the Huber threshold (losses.py)."""

    parts: float = 20.0
    lpips: float = 0.05
    offset: float = 0.001
    scale: float = 0.5
    huber_delta: float = 0.1
    # Not the paper's: a penalty on axis ratios above ANISOTROPY_RATIO (losses.py), against
    # the needles that thin hair and edges grow on real faces; 0 leaves it out.
    anisotropy: float = 0.0
    # Not the paper's: a penalty on a longest axis more than ROD_RATIO (avatar/config.py)
    # times the middle one (losses.py), against the dark dashes in long hair; 0: none.
    rod: float = 0.0


@dataclass(frozen=True)
class LearningRates:
    features: float = 5e-3
    mapping: float = 1e-3
    decoder: float = 2e-3
    # Per-frame refinement of the tracked codes (train/refine.py); 0 leaves the tracking as is.
    codes: float = 0.0


@dataclass(frozen=True)
class TrainConfig:
    resolution: int = 256  # training images are resized to this longer side (pixels)
    stage1_steps: int = 1000  # LOD 0, everything trains
    stage2_steps: int = 500  # several LODs per step, mapping network frozen
    # Not the paper's: with the decoder settled, the feature field alone, levels drawn as in
    # stage 2 (stage 3); then its sparsest level alone, near LOD 1 as `lod1_band` draws it
    # (stage 4), the level LOD 1 draws almost all its features from (docs/quality.md,
    # "Stages 3 and 4").
    stage3_steps: int = 0
    stage4_steps: int = 0
    lods_per_step: int = 5
    lr: LearningRates = field(default_factory=LearningRates)
    lr_final_ratio: float = 0.1  # the rates decay exponentially over the run to this fraction
    loss: LossWeights = field(default_factory=LossWeights)
    # The perceptual term on every k-th step only, weighted k x λ_lpips there (an unbiased
    # estimate of the full term): ST-LPIPS costs more than the avatar on the CPU.
    lpips_every: int = 1
    # "one": in stage 2, the term on one of the step's renders, in turn over the steps and
    # weighted by their count (again unbiased), instead of on every one.
    lpips_levels: str = "all"
    # Not the paper's: in stage 2, this share of the steps draws its sparsest level near LOD 1
    # instead of in its stratum: at 1 - lod1_band v^2 (v uniform in [0, 1), denser toward 1;
    # band 0: at LOD 1 exactly), where a uniform draw almost never reaches the end.
    lod1_share: float = 0.0
    lod1_band: float = 0.0
    avatar: dict = field(default_factory=dict)  # AvatarConfig fields
    checkpoint_every: int = 100  # steps
    seed: int = 0
    threads: int = 0  # CPU threads of torch and the splat kernel; 0 = their default (all)
    device: str = "auto"  # "auto" (CUDA when present), "cpu" or "cuda"
    holdout: str = "last"  # the test frames (HOLDOUTS): the last 10 %, or every tenth
    mask: str = "head"  # MASKS: the tracker's head-and-neck masks, or the whole person's
    frames: int = 0  # train on this many frames of the split, evenly spread; 0: all of them
    # Not the paper's: "region" cuts each render to the tracking's head-and-neck region (the
    # dataset's `region`: what the mask keeps of the truth, from the tracked mesh alone)
    # before the loss, so that hair the mask's straight cuts leave out costs nothing.
    cut: str = "none"
    # Not the paper's: end the run within this many minutes of its start, the stages'
    # steps shortened in one proportion as it goes (time_limit.py); 0: the steps above.
    minutes: float = 0.0

    def __post_init__(self):
        """Bad values raise InputError naming the key (`load` adds the file). JSON allows
        NaN and Infinity: a NaN step count once made a run that trained nothing exit 0."""
        for key in WHOLE_NUMBERS:
            value = getattr(self, key)
            if not _is_whole(value):
                raise InputError(None, key, f"must be a finite whole number, got {value!r:.60}")
            object.__setattr__(self, key, int(value))  # 1e3 in JSON reads as 1000.0
        for key in (*STAGE_STEPS, "seed", "threads"):
            _require(getattr(self, key) >= 0, key, f"must be >= 0, got {getattr(self, key)}")
        _require(
            self.stage1_steps + self.stage2_steps > 0,
            "stage1_steps",
            "stage1_steps + stage2_steps must be > 0",
        )
        _require(
            self.resolution >= 32,
            "resolution",
            f"must be >= 32 px (ST-LPIPS), got {self.resolution}",
        )
        for key in ("lods_per_step", "checkpoint_every", "lpips_every"):
            _require(getattr(self, key) >= 1, key, f"must be >= 1, got {getattr(self, key)}")
        _require(
            self.lpips_levels in LPIPS_LEVELS,
            "lpips_levels",
            f"must be one of {LPIPS_LEVELS}, got {self.lpips_levels!r}",
        )
        _require(
            finite_real(self.minutes) and self.minutes >= 0,
            "minutes",
            f"must be a finite number >= 0 (0: no time limit), got {self.minutes!r:.60}",
        )
        for key in ("lod1_share", "lod1_band"):
            value = getattr(self, key)
            _require(
                finite_real(value) and 0 <= value <= 1,
                key,
                f"must be a number in [0, 1], got {value!r:.60}",
            )
        for group in ("lr", "loss"):
            for f in fields(getattr(self, group)):
                value = getattr(getattr(self, group), f.name)
                ok = finite_real(value) and value >= 0
                _require(
                    ok, f"{group}.{f.name}", f"must be a finite number >= 0, got {value!r:.60}"
                )
        _require(
            self.loss.huber_delta > 0,
            "loss.huber_delta",
            f"must be > 0 (the Huber loss's threshold), got {self.loss.huber_delta!r}",
        )
        ratio = self.lr_final_ratio
        _require(
            finite_real(ratio) and 0 < ratio <= 1,
            "lr_final_ratio",
            f"must be in (0, 1], got {ratio!r}",
        )
        _require(
            self.device in ("auto", "cpu", "cuda"),
            "device",
            f"must be 'auto', 'cpu' or 'cuda', got {self.device!r}",
        )
        _require(self.mask in MASKS, "mask", f"must be one of {MASKS}, got {self.mask!r}")
        _require(self.cut in CUTS, "cut", f"must be one of {CUTS}, got {self.cut!r}")
        _require(self.frames >= 0, "frames", f"must be >= 0 (0: every frame), got {self.frames}")
        _require(
            self.holdout in HOLDOUTS,
            "holdout",
            f"must be one of {HOLDOUTS}, got {self.holdout!r}",
        )
        try:
            avatar = self.avatar_config(n_expr=1)  # reject unknown or invalid avatar fields now
        except ValueError as exc:
            raise InputError(None, "avatar", str(exc)) from exc
        for key in STAGE_STEPS[2:]:
            _require(
                not getattr(self, key) or bool(avatar.levels),
                key,
                "needs a feature field to train (avatar.levels is empty)",
            )

    @property
    def total_steps(self) -> int:
        return sum(self.stage_steps)

    @property
    def stage_steps(self) -> tuple[int, ...]:
        """The steps of stages 1 to 4."""
        return tuple(getattr(self, key) for key in STAGE_STEPS)

    def stage(self, step: int) -> int:
        """The stage (1 to 4) of a step counted from 0; past the end, the last with steps."""
        end, last = 0, 1
        for stage, steps in enumerate(self.stage_steps, start=1):
            last, end = (stage if steps else last), end + steps
            if step < end:
                return stage
        return last

    def avatar_config(self, n_expr: int) -> AvatarConfig:
        known = {f.name for f in fields(AvatarConfig)}
        unknown = sorted(set(self.avatar) - known)
        if unknown:
            raise ValueError(f"unknown avatar config fields {unknown}")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in self.avatar.items()}
        return AvatarConfig(**{"n_expr": n_expr, **values})

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        if not isinstance(data, dict):
            raise ValueError("the training config is not a JSON object")
        data = dict(data)
        for key, kind in (("lr", LearningRates), ("loss", LossWeights)):
            if key in data:
                data[key] = _nested(kind, data[key], key)
        return check_ranges(_nested(cls, data, "config"))

    @classmethod
    def load(cls, path) -> TrainConfig:
        """A config file, or a preset name (PRESETS), as `read` checks it."""
        path = config_path(path)
        return cls.read(load_json(path), path)

    @classmethod
    def read(cls, data: dict, where) -> TrainConfig:
        """`from_dict` with errors naming `where` (the file) and the key; a thread count
        above the machine's cores is lowered to them with a warning."""
        try:
            config = cls.from_dict(data)
        except InputError as exc:
            raise InputError(where, exc.key, exc.problem) from exc
        except ValueError as exc:
            raise InputError(where, None, str(exc)) from exc
        return config.with_usable_threads(where)

    def with_usable_threads(self, where) -> TrainConfig:
        """This config with `threads` at most the machine's cores (0 stays: the default)."""
        if not self.threads:
            return self
        return replace(self, threads=thread_count(self.threads, where, "threads"))


def config_path(path_or_preset) -> Path:
    """A preset's file (PRESETS), else the path itself."""
    name = str(path_or_preset)
    return CONFIG_DIR / f"{name}.json" if name in PRESETS else Path(name)


def config_data(path_or_preset=DEFAULT_PRESET) -> dict:
    """A config file's (or preset's) JSON object as written, checked by TrainConfig: the
    starting point that callers override key by key. InputError names the file."""
    path = config_path(path_or_preset)
    data = load_json(path)
    TrainConfig.read(data, path)
    return data


def _nested(kind, data, name: str):
    if not isinstance(data, dict):
        raise ValueError(f"'{name}' must be a JSON object")
    known = {f.name for f in fields(kind)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown keys in '{name}': {unknown}")
    try:
        return kind(**data)
    except TypeError as exc:
        raise ValueError(f"'{name}': {exc}") from exc


def _is_whole(value) -> bool:
    return finite_real(value) and value == int(value)


def _require(ok: bool, key: str, problem: str) -> None:
    if not ok:
        raise InputError(None, key, problem)
