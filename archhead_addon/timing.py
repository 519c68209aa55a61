"""The one timer of every benchmark: wall-clock milliseconds (time.perf_counter) of repeated
calls, a stopwatch for one long stretch, the named step times of a pipeline (the demo), and
the fixed thread count benchmarks run with. numpy-free and torch-free."""

from __future__ import annotations

import os
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


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


class Stopwatch:
    """Seconds since it was made (a whole report, a training run)."""

    def __init__(self):
        self._start = time.perf_counter()

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self._start


class Steps:
    """Wall-clock seconds per named step, in order, each announced as it starts and ends."""

    def __init__(self, label: str):
        self.label = label
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        watch = Stopwatch()
        print(f"{self.label}: {name} ...", flush=True)
        yield
        self.seconds[name] = watch.seconds
        print(f"{self.label}: {name} {self.seconds[name]:.1f} s", flush=True)


def restart_with_threads(threads: int = 2) -> None:
    """Run this process again, as it was started, with `threads` BLAS / OpenMP threads
    (their libraries read the count once, when they load), unless it already has them."""
    if any(os.environ.get(v) != str(threads) for v in THREAD_VARS):
        env = {**os.environ, **dict.fromkeys(THREAD_VARS, str(threads))}
        os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], env)
