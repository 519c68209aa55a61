"""Upper limits and plausible ranges of the training config's values (TrainConfig checks
the lower bounds and the kinds of value; issue 18 the thread count). A value past its limit
is an InputError naming the key; one past the plausible range trains, with a warning."""

from __future__ import annotations

from dataclasses import fields

from ..io.errors import InputError, warn_input
from ..io.schema import finite_real

# key: (lowest, highest); whole numbers. Above these a run allocates or takes years.
COUNTS = {
    "resolution": (32, 8192),
    "stage1_steps": (0, 10_000_000),
    "stage2_steps": (0, 10_000_000),
    "stage3_steps": (0, 10_000_000),
    "stage4_steps": (0, 10_000_000),
    "lods_per_step": (1, 64),
    "lpips_every": (1, 1_000_000),
    "checkpoint_every": (1, 10_000_000),
}
LR_MAX, LR_PLAUSIBLE = 10.0, 0.1  # Adam's rates; the paper's are 1e-3 to 5e-3
SWITCHED_RATES = ("codes",)  # rates whose 0 turns their part off (train/refine.py)
WEIGHT_MAX, WEIGHT_PLAUSIBLE = 1e6, 1e3  # the paper's λs are 0.001 to 20


def check_ranges(config, where=None):
    """`config` unchanged when every value is in range; InputError naming the key if not."""
    for key, (low, high) in COUNTS.items():
        value = getattr(config, key)
        if not (finite_real(value) and value == int(value) and low <= value <= high):
            raise InputError(
                where, key, f"must be a whole number in {low}..{high}, got {value!r:.60}"
            )
    for f in fields(config.lr):
        positive = f.name not in SWITCHED_RATES
        _check(config.lr, f.name, "lr", 0.0, LR_MAX, LR_PLAUSIBLE, where, positive=positive)
    for f in fields(config.loss):
        _check(config.loss, f.name, "loss", 0.0, WEIGHT_MAX, WEIGHT_PLAUSIBLE, where)
    return config


def _check(group, name, prefix, low, high, plausible, where, positive=False) -> None:
    value, key = getattr(group, name), f"{prefix}.{name}"
    if not (finite_real(value) and low <= value <= high) or (positive and value == 0):
        bound = f"in ({low:g}, {high:g}]" if positive else f"in [{low:g}, {high:g}]"
        raise InputError(where, key, f"must be a finite number {bound}, got {value!r:.60}")
    if value > plausible:
        warn_input(where, key, f"{value:g} is above the plausible {plausible:g}")
