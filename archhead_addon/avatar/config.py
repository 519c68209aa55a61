"""Avatar configuration (stored as JSON in checkpoints) and the names and shapes of its weights.

`parameter_shapes` is the one list of what a checkpoint holds; the torch model is built to
match it (a test holds them together) and the numpy runtime reads weights by these names.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace

from ..io.schema import finite_real

# the five decoder heads, in decoding order, and the raw output widths of the first four (the
# colour head's depends on the SH degree: AvatarConfig.head_outputs)
HEADS = ("offset", "scale", "rotation", "opacity", "colour")
FIXED_OUTPUTS = {"offset": 3, "scale": 3, "rotation": 4, "opacity": 1}
# What checkpoints written before these fields existed hold: degree-3 SH blended as display
# values.
LEGACY = {"sh_degree": 3, "colour_space": "display"}
COLOUR_SPACES = ("linear", "display")  # splat/colour_space.py
JAW_DIM, EYES_DIM = 3, 6
QUAT_EPS = 1e-8  # below this norm a raw quaternion is replaced by the identity
# A rod: a Gaussian whose longest axis is more than this many times its middle one, drawn as a
# dash (the hair's dark dashes; `loss.rod` pulls on them, `evaluate` counts them)
ROD_RATIO = 3.0


@dataclass(frozen=True)
class AvatarConfig:
    s_max: int = 256
    s_min: int = 64
    levels: tuple[int, ...] = (256, 128, 64)  # feature-field resolutions; () = no feature map
    feature_dim: int = 64
    tau: float = 0.35  # blend temperature of eq. 5
    n_expr: int = 100  # expression codes the mapping network reads
    drive_dim: int = 20  # K
    pe_freqs: int = 12  # octaves of the positional encoding (finest period 2 pi / 2^(n-1) m)
    mapping_hidden: int = 128
    hidden: int = 32  # hidden width of the offset, scale, rotation and opacity heads
    colour_hidden: int = 64  # hidden width of the colour head (48 SH outputs, most detail)
    head_layers: int = 2  # hidden layers per head; the first is fused across the five heads
    offset_unit: float = 0.01  # metres per unit of the offset head's output
    log_scale_min: float = math.log(1e-4)  # clamp of the log scales (0.1 mm .. 5 cm)
    log_scale_max: float = math.log(5e-2)
    init_opacity: float = 0.2
    init_rgb: tuple[float, float, float] = (0.5, 0.5, 0.5)
    pe_centre: tuple[float, float, float] = (0.0, 0.0, 0.0)  # head centre, metres
    # Colour as SH of this degree (0 = one RGB per Gaussian, 3 = 3DGS's 16 coefficients).
    # 0 by default: with one fixed training camera the higher bands do not learn view
    # dependence but extra colour, which a display that shows the DC term loses
    # (docs/training.md, "Colour").
    sh_degree: int = 0
    # How colours blend: "linear" (as Blender blends them; the image is sRGB-encoded at the
    # end) or "display" (3DGS's, blended as sRGB values). splat/colour_space.py says why.
    colour_space: str = "linear"

    def __post_init__(self):
        _check_types_and_limits(self)
        if not 1 <= self.s_min <= self.s_max:
            raise ValueError(f"need 1 <= s_min <= s_max, got {self.s_min}, {self.s_max}")
        if len(set(self.levels)) != len(self.levels) or any(s < 1 for s in self.levels):
            raise ValueError(f"feature levels must be distinct positive sizes: {self.levels}")
        if (
            self.tau <= 0
            or self.head_layers < 1
            or self.log_scale_min >= self.log_scale_max
            or min(self.hidden, self.colour_hidden, self.feature_dim, self.drive_dim) < 1
            or self.pe_freqs < 0
            or not 0 <= self.sh_degree <= 3
        ):
            raise ValueError(
                "need tau > 0, head_layers >= 1, positive widths, pe_freqs >= 0, "
                "sh_degree in 0..3 and log_scale_min < log_scale_max"
            )

    @property
    def pe_dim(self) -> int:
        """The position, then the sine and cosine of each octave: 75 for 12 octaves."""
        return 3 + 2 * 3 * self.pe_freqs

    @property
    def in_dim(self) -> int:
        """Decoder input per texel: PE (75) | feature (64, if any) | drive (K) | l."""
        return self.pe_dim + (self.feature_dim if self.levels else 0) + self.drive_dim + 1

    @property
    def sh_coeffs(self) -> int:
        return (self.sh_degree + 1) ** 2

    def head_outputs(self) -> dict[str, int]:
        """Each head's raw output width, in HEADS order."""
        return {**FIXED_OUTPUTS, "colour": 3 * self.sh_coeffs}

    def head_width(self, name: str) -> int:
        return self.colour_hidden if name == "colour" else self.hidden

    def head_slices(self) -> dict[str, slice]:
        """Each head's rows in the fused first layer's output, in HEADS order."""
        out, start = {}, 0
        for name in HEADS:
            out[name] = slice(start, start + self.head_width(name))
            start += self.head_width(name)
        return out

    @property
    def fused_width(self) -> int:
        return sum(self.head_width(name) for name in HEADS)

    @property
    def mapping_in(self) -> int:
        return self.n_expr + JAW_DIM + EYES_DIM

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> AvatarConfig:
        """Raises ValueError (with the reason) on bad JSON or unknown / ill-typed fields."""
        data = json.loads(text)
        if not isinstance(data, dict):
            raise ValueError("the config is not a JSON object")
        known = {f.name for f in fields(cls)}
        if set(data) - known:
            raise ValueError(f"unknown config fields {sorted(set(data) - known)}")
        for key, value in LEGACY.items():
            data.setdefault(key, value)
        for key in ("levels", "init_rgb", "pe_centre"):
            if key in data:
                data[key] = tuple(data[key])
        try:
            return cls(**data)
        except TypeError as exc:
            raise ValueError(str(exc)) from exc


# Upper limits of the size fields: far above the paper's model, below what would exhaust
# memory the moment a model is built (a feature map of 2^20 texels a side).
SIZE_LIMITS = {
    "s_max": 4096,
    "s_min": 4096,
    "feature_dim": 1024,
    "n_expr": 10_000,
    "drive_dim": 1024,
    "pe_freqs": 30,
    "mapping_hidden": 4096,
    "hidden": 4096,
    "colour_hidden": 4096,
    "head_layers": 16,
}
MAX_LEVEL = 4096
# Finite but absurd values refused, by field: (low, high, why). A tau of 1e-300 makes every
# blend weight exp(-1e300) = 0 (NaN texels); below 0.02 the weights of a level ln 4096 away
# underflow float64; above 100 every level weighs the same.
RANGES = {
    "tau": (0.02, 100.0, "the blend temperature of eq. 5; the paper's is 0.35"),
    "offset_unit": (1e-6, 1.0, "metres per unit of the offset head's output"),
    "log_scale_min": (math.log(1e-7), math.log(1.0), "log of a Gaussian's scale in metres"),
    "log_scale_max": (math.log(1e-7), math.log(1.0), "log of a Gaussian's scale in metres"),
    "init_opacity": (1e-6, 1 - 1e-6, "an opacity in (0, 1): its logit is the bias"),
    "init_rgb": (0.0, 1.0, "colour components in 0..1"),
    "pe_centre": (-10.0, 10.0, "metres from the FLAME origin"),
}


def _check_types_and_limits(config: AvatarConfig) -> None:
    """ValueError naming the field: ints that are not ints, numbers that are not finite
    (NaN passes every comparison, so `tau <= 0` alone let a NaN tau through), sizes above
    SIZE_LIMITS."""
    for f in fields(config):
        value = getattr(config, f.name)
        if f.name in SIZE_LIMITS:
            if not _is_int(value) or not 0 <= value <= SIZE_LIMITS[f.name]:
                raise ValueError(f"{f.name} must be an integer in 0..{SIZE_LIMITS[f.name]}")
        elif f.name == "levels":
            if not all(_is_int(s) and s <= MAX_LEVEL for s in value) or len(value) > 8:
                raise ValueError(f"levels must be at most 8 integers up to {MAX_LEVEL}")
        elif f.name == "colour_space":
            if value not in COLOUR_SPACES:
                raise ValueError(f"colour_space must be one of {COLOUR_SPACES}, got {value!r}")
        elif isinstance(value, tuple):
            if len(value) != 3 or not all(finite_real(v) for v in value):
                raise ValueError(f"{f.name} must be three finite numbers")
        elif not finite_real(value):
            raise ValueError(f"{f.name} must be a finite number, got {value!r:.40}")
        if f.name in RANGES:
            low, high, why = RANGES[f.name]
            if not all(low <= v <= high for v in (value if isinstance(value, tuple) else (value,))):
                raise ValueError(
                    f"{f.name} must be in {low:.3g}..{high:.3g} ({why}), got {value!r:.60}"
                )


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


# Table 4 of the paper: the full model and its ablations, as config changes
ABLATIONS = {
    "full": {},
    "no_fmap": {"levels": ()},
    "fmap64": {"levels": (64,)},
    "fmap128": {"levels": (128,)},
    "fmap256": {"levels": (256,)},
}


def ablation(name: str, **changes) -> AvatarConfig:
    if name not in ABLATIONS:
        raise ValueError(f"unknown ablation {name!r}; choose from {sorted(ABLATIONS)}")
    return replace(AvatarConfig(**changes), **ABLATIONS[name])


def parameter_shapes(config: AvatarConfig) -> dict[str, tuple[int, ...]]:
    """Every learned array by its checkpoint name (the torch state_dict key)."""
    shapes: dict[str, tuple[int, ...]] = {}
    for s in config.levels:
        shapes[f"features.{s}"] = (config.feature_dim, s, s)
    shapes["mapping.0.weight"] = (config.mapping_hidden, config.mapping_in)
    shapes["mapping.0.bias"] = (config.mapping_hidden,)
    shapes["mapping.2.weight"] = (config.drive_dim, config.mapping_hidden)
    shapes["mapping.2.bias"] = (config.drive_dim,)
    shapes["decoder.first.weight"] = (config.fused_width, config.in_dim)
    shapes["decoder.first.bias"] = (config.fused_width,)
    for name, width in config.head_outputs().items():
        h = config.head_width(name)
        for i in range(config.head_layers - 1):
            shapes[f"decoder.heads.{name}.hidden.{i}.weight"] = (h, h)
            shapes[f"decoder.heads.{name}.hidden.{i}.bias"] = (h,)
        shapes[f"decoder.heads.{name}.out.weight"] = (width, h)
        shapes[f"decoder.heads.{name}.out.bias"] = (width,)
    return shapes
