"""The one timer of every benchmark: wall-clock milliseconds (time.perf_counter) of repeated
calls, and the named step times of a pipeline (the demo). numpy-free and torch-free."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass


@dataclass(frozen=True)
class Timing:
    times_ms: tuple[float, ...]

    @property
    def median_ms(self) -> float:
        return statistics.median(self.times_ms)

    @property
    def mean_ms(self) -> float:
        return statistics.fmean(self.times_ms)

    @property
    def min_ms(self) -> float:
        return min(self.times_ms)


def time_calls(fn: Callable, repeats: int, warmup: int = 0, with_index: bool = False) -> Timing:
    """Time `repeats` calls of fn() (fn(i) with_index, i = 0 .. repeats - 1) after `warmup`
    untimed ones."""
    call = fn if with_index else (lambda _i: fn())
    for i in range(warmup):
        call(i)
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        call(i)
        times.append(1e3 * (time.perf_counter() - start))
    return Timing(tuple(times))


class Steps:
    """Wall-clock seconds per named step, in order, each announced as it starts and ends."""

    def __init__(self, label: str):
        self.label = label
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        print(f"{self.label}: {name} ...", flush=True)
        yield
        self.seconds[name] = time.perf_counter() - start
        print(f"{self.label}: {name} {self.seconds[name]:.1f} s", flush=True)
