"""Checks every format's validation shares: numeric and integer arrays from untrusted
objects, finite values, and ranges: past a hard limit an InputError, past a plausible one an
InputWarning (the value may be real, but usually means a unit or format mix-up)."""

from __future__ import annotations

import math
from numbers import Real

import numpy as np

from .errors import InputError, warn_input

FLOAT32_MAX = float(np.finfo(np.float32).max)


def finite_real(value) -> bool:
    """A finite real number and not a bool (JSON's true is an int to Python); an integer
    beyond float's range (JSON's 1 followed by 400 zeros) is not finite."""
    if isinstance(value, bool) or not isinstance(value, Real):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


MAX_LIST_ITEMS = 1 << 20  # Python lists converted to arrays (pickled codes): elements


def numeric(value, path, key) -> np.ndarray:
    """`value` as a float64 array: numbers, real arrays and small lists of them. Complex
    numbers, text and objects are refused, not cast (a cast drops or garbles them), and so are
    booleans: no format stores a code, a camera or a count as true/false, and a cast makes
    every value 0 or 1 (see `_refuse_bool`)."""
    if isinstance(value, list | tuple):
        _count_items(value, path, key)
    if isinstance(value, bool | int | float | np.number | np.bool_ | list | tuple):
        try:
            value = np.asarray(value)
        except ValueError as exc:  # ragged lists: rows of different lengths
            raise InputError(path, key, "nested lists of unequal lengths, not an array") from exc
    _refuse_bool(value, path, key)
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "iuf":
        kind = value.dtype if isinstance(value, np.ndarray) else type(value).__name__
        raise InputError(path, key, f"not a real numeric array ({kind})")
    value = flush_subnormal(value, path, key)
    try:
        return value.astype(np.float64)
    except OverflowError as exc:  # only huge Python ints get here
        raise InputError(path, key, f"values outside float64 range ({exc})") from exc


F32_TINY = float(np.finfo(np.float32).tiny)


def flush_subnormal(value: np.ndarray, path, key) -> np.ndarray:
    """`value` with subnormal float32 values (nonzero, below 1.2e-38) set to 0, and an
    InputWarning saying how many: no tracker or trainer writes one (an optimiser moves a
    value by far more), they are what zeroed or flipped exponent bits leave."""
    if value.dtype.kind != "f" or value.dtype.itemsize != 4:
        return value
    bad = (value != 0) & (np.abs(value) < F32_TINY)
    if not bad.any():
        return value
    first = np.unravel_index(int(np.argmax(bad)), value.shape)
    warn_input(
        path,
        key,
        f"{int(bad.sum())} subnormal float32 value(s) (first {value[first]:.3g} at index "
        f"{[int(i) for i in first]}): damaged exponent bits; set to 0",
    )
    return np.where(bad, np.float32(0), value)


def _refuse_bool(value, path, key) -> None:
    """InputError for booleans (a bool array, or True/False) where numbers are expected."""
    if isinstance(value, bool | np.bool_) or (
        isinstance(value, np.ndarray) and value.dtype.kind == "b"
    ):
        raise InputError(path, key, "booleans where numbers are expected (no reader casts them)")


def _count_items(value, path, key, depth: int = 0, budget: list | None = None) -> None:
    """Bound a nested list before numpy walks it (shared sublists multiply its size)."""
    budget = budget if budget is not None else [MAX_LIST_ITEMS]
    if depth > 8:
        raise InputError(path, key, "lists nested deeper than 8 levels")
    budget[0] -= len(value)
    if budget[0] < 0:
        raise InputError(path, key, f"more than {MAX_LIST_ITEMS} list elements")
    for item in value:
        if isinstance(item, list | tuple):
            _count_items(item, path, key, depth + 1, budget)


def integers(value, path, key) -> np.ndarray:
    """`value` as int64: integer arrays, or floats that are whole numbers within int64."""
    _refuse_bool(value, path, key)
    if isinstance(value, np.ndarray) and value.dtype.kind in "iu":
        if value.dtype == np.uint64 and value.size and value.max() > np.iinfo(np.int64).max:
            raise InputError(path, key, "integers beyond int64")
        return value.astype(np.int64)
    array = numeric(value, path, key)
    if not np.isfinite(array).all() or (np.abs(array) >= 2.0**63).any():
        raise InputError(path, key, "integers expected, found NaN, Inf or values beyond int64")
    if (array != np.round(array)).any():
        raise InputError(path, key, "integers expected, found fractional values")
    return array.astype(np.int64)


def check_finite(array: np.ndarray, path, key, along: str | None = None) -> None:
    """InputError for NaN or Inf, giving the first bad index along axis 0 (`along` names it)."""
    bad = ~np.isfinite(array)
    if bad.any():
        where = ""
        if along and array.ndim:
            where = f" at {along} index {int(np.argmax(bad.reshape(len(array), -1).any(1)))}"
        raise InputError(path, key, "NaN or Inf" + where)


def check_range(array, path, key, *, hard: float = FLOAT32_MAX, plausible=None, reason=""):
    """Finite values with magnitude at most `hard` (else InputError) and, when `plausible`
    is given, at most it (else one InputWarning naming the largest and the reason)."""
    array = np.asarray(array)
    check_finite(array, path, key)
    if not array.size:
        return
    largest = float(np.abs(array).max())
    if largest > hard:
        why = "above float32's range: Inf in the runtime" if hard == FLOAT32_MAX else reason
        raise InputError(path, key, f"magnitude {largest:.3g} is above {hard:.3g} ({why})")
    if plausible is not None and largest > plausible:
        warn_input(
            path, key, f"magnitude {largest:.3g} is above the plausible {plausible:g} ({reason})"
        )
