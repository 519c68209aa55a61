"""`train_state.pt` read back for a resume: through the bounded torch.save reader
(io/torch_zip.py: no torch.load, no code, sizes and nesting bounded), then checked key by
key, so a damaged or foreign file is an InputError naming the key instead of a KeyError or
a NaN deep inside the optimizer. The optimizer's groups and per-parameter state are checked
against the saved model's tensors (and the refinement's), in the order `Trainer` builds its
Adam groups: torch's `load_state_dict` checks only the group sizes, and a moment of the
wrong shape would fail inside Adam's first step. Finite values no run produces (a weight or a
moment of 1e30) are refused too: past PARAMETER_LIMIT and MOMENT_LIMITS below. Last, the
state's checksum (io/checksum.py, `tree_checksum`; written by `Trainer.save`) is checked, so
a damaged or edited value no check can tell from a real one is refused too; a state from
before checksums is read with a warning."""

from __future__ import annotations

import json
import math

import numpy as np

from ..avatar.config import AvatarConfig, parameter_shapes
from ..io.checksum import KEY, tree_checksum, verify
from ..io.errors import InputError, warn_input
from ..io.schema import check_finite, finite_real
from ..io.torch_zip import load_torch_file
from ..sequences.validation import PLAUSIBLE, TRAIN_FACTOR
from .config import TrainConfig
from .config_ranges import LR_MAX

STATE_FORMAT, STATE_VERSION = "archhead-train-state", 1
# Trainer's Adam groups, in order, each of the model's tensors under that prefix (loop.py);
# then one group "codes" per refined code, one parameter per frame (refine.py)
MODEL_GROUPS = ("features", "mapping", "decoder")
ADAM_STATE = ("step", "exp_avg", "exp_avg_sq")
# Finite magnitudes no training run produces (issue 33), refused with the key named: a
# weight of 1e30 is finite, yet its forward pass is Inf and its first step a NaN.
# - Parameters (the model's tensors, the refined code deltas, identity_offset): above 1e6,
#   float32's spacing is 0.0625 or more, coarser than Adam's steps (about the rate, 1e-3 to
#   5e-3, at most 0.1 plausibly): Adam could not have brought a weight there, nor move it
#   once there, and one such weight saturates every activation after it.
# - exp_avg, a running mean of gradients: a gradient of 1e6 on a loss of order 1 is a run
#   that has diverged (the next step would be one of about the rate, in a random direction).
# - exp_avg_sq, a running mean of squared gradients: the square of that limit.
PARAMETER_LIMIT = 1e6
MOMENT_LIMITS = {"exp_avg": 1e6, "exp_avg_sq": 1e12}
# Adam's settings in each parameter group, which torch's load_state_dict takes from the file:
# (lowest, highest) of the numbers (betas each), and the switches the trainer leaves off
# (maximize climbs the loss; amsgrad needs a moment the trainer never keeps)
ADAM_RANGES = {"lr": (0.0, LR_MAX), "betas": (0.0, 0.999999), "eps": (0.0, 1.0),
               "weight_decay": (0.0, 1.0)}  # fmt: skip
ADAM_OFF = ("amsgrad", "maximize")
ADAM_FLAGS = ("foreach", "capturable", "differentiable", "fused", "decoupled_weight_decay")


def read_train_state(path) -> dict:
    """The state as `Trainer.save` wrote it, arrays as numpy; InputError on anything off."""
    try:
        state = load_torch_file(path)
    except InputError as exc:
        raise InputError(path, exc.key, f"unreadable training state: {exc.problem}") from exc
    if (
        not isinstance(state, dict)
        or not isinstance(state.get("format"), str)
        or state.get("format") != STATE_FORMAT
        or not isinstance(state.get("version"), int)
        or isinstance(state.get("version"), bool)
        or state.get("version") != STATE_VERSION
    ):
        raise InputError(path, None, f"not an ArchHead training state of version {STATE_VERSION}")
    step, elapsed = state.get("step"), state.get("elapsed")
    if not isinstance(step, int) or isinstance(step, bool) or not 0 <= step < 1 << 40:
        raise InputError(path, "step", f"expected a whole number >= 0, found {step!r:.40}")
    if not _real_in(elapsed, 0.0, math.inf):
        raise InputError(path, "elapsed", f"expected seconds >= 0, found {elapsed!r:.40}")
    parsed = {}
    for key, parse in (("config", _train_config), ("avatar_config", AvatarConfig.from_json)):
        try:
            parsed[key] = parse(_text(state, key, path))
        except (ValueError, TypeError, RecursionError) as exc:
            raise InputError(path, key, f"invalid: {exc}") from exc
    if state.get("model_id") is not None:
        _text(state, "model_id", path)
    _model(state.get("model"), path, parameter_shapes(parsed["avatar_config"]))
    offset = state.get("identity_offset")
    if offset is not None:
        _tensors({"": offset}, path, "identity_offset", PARAMETER_LIMIT)
        if offset.ndim != 2 or offset.shape[1] != 3:
            raise InputError(path, "identity_offset", f"expected (V, 3), found {offset.shape}")
    if state.get("refinement") is not None:  # lr.codes > 0 (train/refine.py)
        _tensors(state["refinement"], path, "refinement", PARAMETER_LIMIT)
    if getattr(parsed["config"].lr, "codes", 0) > 0 and not state.get("refinement"):
        raise InputError(path, "refinement", "missing: the run's config refines the codes")
    _optimizer(state.get("optimizer"), path, _parameters(state, path))
    # last, as the avatar checkpoint's: a value the checks above name is reported as that
    if not verify(state, path, tree_checksum):
        warn_input(
            path,
            None,
            f"carries no {KEY} (written before training states had one): "
            "its content is read unchecked",
        )
    return state


def _real_in(value, low: float, high: float) -> bool:
    return finite_real(value) and low <= value <= high


def _adam_settings(group: dict, path, where: str) -> None:
    """The Adam settings of one parameter group in range (torch resumes with them)."""
    for name, (low, high) in ADAM_RANGES.items():
        value = group.get(name)
        if name != "lr" and name not in group:
            continue  # torch's defaults
        values = value if name == "betas" and isinstance(value, list | tuple) else [value]
        if (name == "betas" and len(values) != 2) or not all(
            _real_in(v, low, high) for v in values
        ):
            raise InputError(
                path,
                f"{where}.{name}",
                f"expected numbers in {low:g}..{high:g}, found {value!r:.60}",
            )
    for name in ADAM_OFF + ADAM_FLAGS:
        value = group.get(name)
        if not (value is None or value is False or (name in ADAM_FLAGS and value is True)):
            raise InputError(
                path,
                f"{where}.{name}",
                f"{value!r:.40}: the trainer's Adam has it off"
                if name in ADAM_OFF
                else f"expected true, false or null, found {value!r:.40}",
            )


def _train_config(text: str) -> TrainConfig:
    return TrainConfig.from_dict(json.loads(text))


def _text(state: dict, key: str, path) -> str:
    value = state.get(key)
    if not isinstance(value, str):
        raise InputError(path, key, "missing or not text")
    return value


def _tensors(value, path, key: str, limit: float | None = None) -> None:
    if not isinstance(value, dict) or not value:
        raise InputError(path, key, "missing or not a dict of arrays")
    for name, array in value.items():
        where = f"{key}.{name}"
        if not isinstance(array, np.ndarray) or array.dtype.kind not in "fiub":
            raise InputError(path, where, "not a real-valued tensor")
        check_finite(array, path, where)
        if limit is not None:
            _magnitude(array, path, where, limit)


def _magnitude(array: np.ndarray, path, key: str, limit: float) -> None:
    """InputError when a finite value of `array` is beyond `limit` in magnitude."""
    biggest = float(np.abs(array).max()) if array.size and array.dtype.kind == "f" else 0.0
    if biggest > limit:
        raise InputError(
            path,
            key,
            f"magnitude {biggest:.3g} is above {limit:g}: no training run reaches it "
            "(a damaged or diverged state)",
        )


def _model(value, path, shapes: dict[str, tuple[int, ...]]) -> None:
    _tensors(value, path, "model")
    shape = value.get("identity_shape")
    if shape is None:
        raise InputError(path, "model.identity_shape", "missing (the subject's FLAME shape)")
    if shape.ndim != 1 or not shape.size or shape.dtype.kind != "f":
        raise InputError(
            path,
            "model.identity_shape",
            f"expected (S,) floating-point coefficients, found {shape.dtype} {shape.shape}",
        )
    limit = TRAIN_FACTOR * PLAUSIBLE["shape"][0]  # as the tracking's (sequences/validation.py)
    if np.abs(shape).max() > limit:
        raise InputError(
            path, "model.identity_shape", f"magnitude {np.abs(shape).max():.3g} is above {limit:g}"
        )
    for key, want in shapes.items():  # strict, as the avatar's load_state_dict
        if key not in value:
            raise InputError(path, f"model.{key}", f"missing (avatar_config needs {want})")
        if value[key].shape != want:
            raise InputError(
                path, f"model.{key}", f"shape {value[key].shape}, avatar_config needs {want}"
            )
        _magnitude(value[key], path, f"model.{key}", PARAMETER_LIMIT)
    extra = sorted(set(value) - set(shapes) - {"identity_shape"})
    if extra:
        raise InputError(path, f"model.{extra[0]}", "not a tensor of the avatar_config's model")


def _parameters(state: dict, path) -> list[tuple[str, list[tuple[int, ...]]]]:
    """(group name, the shapes of its parameters) of every Adam group a resumed Trainer
    builds from this state, in order."""
    groups = [
        (g, [a.shape for k, a in state["model"].items() if k.startswith(g + ".")])
        for g in MODEL_GROUPS
    ]
    for key, deltas in (state.get("refinement") or {}).items():
        if deltas.ndim < 1 or not len(deltas):
            raise InputError(
                path, f"refinement.{key}", f"expected (frames, ...), found {deltas.shape}"
            )
        groups.append(("codes", [deltas.shape[1:]] * len(deltas)))
    return groups


def _optimizer(value, path, expected: list[tuple[str, list[tuple[int, ...]]]]) -> None:
    if not isinstance(value, dict):
        raise InputError(path, "optimizer", "missing or not a dict")
    per_param, groups = value.get("state"), value.get("param_groups")
    if not isinstance(per_param, dict) or not isinstance(groups, list) or not groups:
        raise InputError(path, "optimizer", "needs 'state' (a dict) and 'param_groups' (a list)")
    if len(groups) != len(expected):
        raise InputError(
            path,
            "optimizer.param_groups",
            f"{len(groups)} parameter groups, the saved model and refinement need "
            f"{len(expected)} ({', '.join(name for name, _ in expected)})",
        )
    shapes: dict[int, tuple[int, ...]] = {}
    for i, (group, (name, want)) in enumerate(zip(groups, expected, strict=True)):
        where = f"optimizer.param_groups[{i}]"
        if not isinstance(group, dict):
            raise InputError(path, where, "not a dict")
        params = group.get("params")
        _adam_settings(group, path, where)
        if not isinstance(params, list) or not all(
            isinstance(p, int) and not isinstance(p, bool) for p in params
        ):
            raise InputError(path, f"{where}.params", "not a list of ints")
        if group.get("name") != name:
            raise InputError(
                path, f"{where}.name", f"expected '{name}', found {group.get('name')!r:.40}"
            )
        if len(params) != len(want):
            raise InputError(
                path,
                f"{where}.params",
                f"{len(params)} parameters, the saved '{name}' tensors are {len(want)}",
            )
        for index, shape in zip(params, want, strict=True):
            if index in shapes:
                raise InputError(path, f"{where}.params", f"parameter {index} listed twice")
            shapes[index] = tuple(shape)
    for index, entry in per_param.items():
        where = f"optimizer.state.{index}"
        if index not in shapes:
            raise InputError(path, where, "state of a parameter no group lists")
        _tensors(entry, path, where)
        for name in ADAM_STATE:  # Adam reads all three once a parameter has a state
            if name not in entry:
                raise InputError(
                    path,
                    f"{where}.{name}",
                    "missing (Adam's state has all of step, exp_avg, exp_avg_sq)",
                )
        step = entry["step"]
        if step.shape != () or not (0 <= step < 1 << 40) or step != np.round(step):
            raise InputError(
                path, f"{where}.step", f"expected one whole number >= 0, found {step!r:.60}"
            )
        if (entry["exp_avg_sq"] < 0).any():
            raise InputError(path, f"{where}.exp_avg_sq", "negative: a mean of squares is >= 0")
        for name, limit in MOMENT_LIMITS.items():
            _magnitude(entry[name], path, f"{where}.{name}", limit)
        for name, moment in entry.items():
            if name != "step" and moment.shape != shapes[index]:
                raise InputError(
                    path,
                    f"{where}.{name}",
                    f"shape {moment.shape}, its parameter's is {shapes[index]}",
                )
