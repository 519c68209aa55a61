"""`train_state.pt` read back for a resume: through the bounded torch.save reader
(io/torch_zip.py: no torch.load, no code, sizes and nesting bounded), then checked key by
key, so a damaged or foreign file is an InputError naming the key instead of a KeyError or
a NaN deep inside the optimizer."""

from __future__ import annotations

import json
import math

import numpy as np

from ..avatar.config import AvatarConfig
from ..io.errors import InputError
from ..io.schema import check_finite
from ..io.torch_zip import load_torch_file
from .config import TrainConfig

STATE_FORMAT, STATE_VERSION = "archhead-train-state", 1


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
        or state.get("version") != STATE_VERSION
    ):
        raise InputError(path, None, f"not an ArchHead training state of version {STATE_VERSION}")
    step, elapsed = state.get("step"), state.get("elapsed")
    if not isinstance(step, int) or isinstance(step, bool) or not 0 <= step < 1 << 40:
        raise InputError(path, "step", f"expected a whole number >= 0, found {step!r:.40}")
    if not isinstance(elapsed, int | float) or not (math.isfinite(elapsed) and elapsed >= 0):
        raise InputError(path, "elapsed", f"expected seconds >= 0, found {elapsed!r:.40}")
    for key, parse in (("config", _train_config), ("avatar_config", AvatarConfig.from_json)):
        try:
            parse(_text(state, key, path))
        except (ValueError, TypeError, RecursionError) as exc:
            raise InputError(path, key, f"invalid: {exc}") from exc
    if state.get("model_id") is not None:
        _text(state, "model_id", path)
    _tensors(state.get("model"), path, "model")
    offset = state.get("identity_offset")
    if offset is not None:
        _tensors({"": offset}, path, "identity_offset")
        if offset.ndim != 2 or offset.shape[1] != 3:
            raise InputError(path, "identity_offset", f"expected (V, 3), found {offset.shape}")
    _optimizer(state.get("optimizer"), path)
    return state


def _train_config(text: str) -> TrainConfig:
    return TrainConfig.from_dict(json.loads(text))


def _text(state: dict, key: str, path) -> str:
    value = state.get(key)
    if not isinstance(value, str):
        raise InputError(path, key, "missing or not text")
    return value


def _tensors(value, path, key: str) -> None:
    if not isinstance(value, dict) or not value:
        raise InputError(path, key, "missing or not a dict of arrays")
    for name, array in value.items():
        where = f"{key}.{name}"
        if not isinstance(array, np.ndarray) or array.dtype.kind not in "fiub":
            raise InputError(path, where, "not a real-valued tensor")
        check_finite(array, path, where)


def _optimizer(value, path) -> None:
    if not isinstance(value, dict):
        raise InputError(path, "optimizer", "missing or not a dict")
    per_param, groups = value.get("state"), value.get("param_groups")
    if not isinstance(per_param, dict) or not isinstance(groups, list) or not groups:
        raise InputError(path, "optimizer", "needs 'state' (a dict) and 'param_groups' (a list)")
    for index, entry in per_param.items():
        _tensors(entry, path, f"optimizer.state.{index}")
    for i, group in enumerate(groups):
        lr = group.get("lr") if isinstance(group, dict) else None
        params = group.get("params") if isinstance(group, dict) else None
        if not isinstance(lr, int | float) or not (math.isfinite(lr) and lr >= 0):
            raise InputError(path, f"optimizer.param_groups[{i}].lr", "not a finite rate >= 0")
        if not isinstance(params, list) or not all(isinstance(p, int) for p in params):
            raise InputError(path, f"optimizer.param_groups[{i}].params", "not a list of ints")
