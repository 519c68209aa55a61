"""Thread counts, held to the cores this process may run on.

More threads than cores is never faster, and far more is fatal: 1e6 splat-kernel threads
segfault, large OpenMP teams under a memory cap make the runtime exit the whole process
(Blender with it), and `"threads": 1000000` in a training config hangs. Every count read from a
file, a setting, an argument or the environment goes through `thread_count` (or, for the
variables the OpenMP and BLAS runtimes read when they load, `limit_thread_environment`).
Code that runs numpy products on threads of its own holds BLAS to one thread meanwhile
(`one_blas_thread`): two callers each asking OpenBLAS for every core leave the cores waiting
on each other, 1.6x the CPU time for the same work.
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from numbers import Real

from .io.errors import InputError, warn_input

# Read by OpenMP (torch, the splat kernel) and by numpy's BLAS when they load.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def machine_cores() -> int:
    """The cores this process may use (its affinity mask where the system has one)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):  # macOS, Windows
        return max(os.cpu_count() or 1, 1)


def default_threads() -> int:
    """What a count of 0 means: OMP_NUM_THREADS when it is set lower, else every core."""
    cores = machine_cores()
    asked = _leading_count(os.environ.get("OMP_NUM_THREADS", ""))
    return min(asked, cores) if asked else cores


def thread_count(value, where=None, key: str = "threads") -> int:
    """`value` as a thread count in 1 .. machine_cores(): 0 or less is the default
    (`default_threads`); more than the cores is clamped to them with an InputWarning that
    names `where` and `key`. A value that is not a whole number is an InputError."""
    whole = isinstance(value, Real) and not isinstance(value, bool)  # numpy's too
    if not (whole and math.isfinite(value) and value == int(value)):
        raise InputError(where, key, f"a thread count must be a whole number, got {value!r}")
    value = int(value)
    if value <= 0:
        return default_threads()
    cores = machine_cores()
    return _too_many(where, key, value, cores) if value > cores else value


def limit_thread_environment(environ=None) -> None:
    """Lower THREAD_VARIABLES above the core count to it, with a warning: call before torch
    or the splat kernel loads OpenMP (they read them once), and before starting children."""
    environ = os.environ if environ is None else environ
    cores = machine_cores()
    for name in THREAD_VARIABLES:
        asked = _leading_count(environ.get(name, ""))
        if asked and asked > cores:
            environ[name] = str(_too_many("environment", name, asked, cores))


# How long an idle OpenMP thread spins for the next parallel region before it sleeps
# (GNU OpenMP's iterations; a few microseconds). docs/training_profile.md has the figures.
SPIN_COUNT = 2000
WAITING = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")  # the variables that set how they wait
QUIET_LOAD = 0.5  # runnable processes, the last minute's average, that still leave a core free


def choose_openmp_waiting(environ=None) -> str:
    """How torch's and the kernel's OpenMP threads wait between parallel regions: call before
    torch loads, which reads it once. Returns what it chose, for the log. Sleeping at once
    (OMP_WAIT_POLICY=PASSIVE) costs a wake-up per region, a fifth of a CPU training step on
    quiet cores; spinning while other jobs want the cores made small operations 20-30x
    slower. So: a short spin (GOMP_SPINCOUNT) when the cores are quiet, and PASSIVE when they
    are not; left alone when either variable is set."""
    environ = os.environ if environ is None else environ
    if any(k in environ for k in WAITING):
        return "OpenMP waiting as set in the environment"
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # Windows
        load = math.inf
    if load <= QUIET_LOAD:
        environ["GOMP_SPINCOUNT"] = str(SPIN_COUNT)
        return f"OpenMP threads spin briefly (quiet cores: load {load:.2f})"
    environ["OMP_WAIT_POLICY"] = "PASSIVE"
    shown = "unknown" if math.isinf(load) else f"{load:.2f}"
    return f"OpenMP threads sleep while they wait (other jobs on the cores: load {shown})"


def openmp_waiting_env() -> dict[str, str]:
    """`choose_openmp_waiting`'s choice as the variables to give a child process, this
    process's own environment left alone (Blender launching the stages of Avatar from Video)."""
    chosen = dict(os.environ)
    choose_openmp_waiting(chosen)
    return {k: chosen[k] for k in WAITING if k in chosen}


@contextmanager
def one_blas_thread() -> Iterator[bool]:
    """Holds numpy's OpenBLAS to one thread until the block ends and yields True; yields
    False, changing nothing, where numpy's BLAS is not an OpenBLAS this process has loaded
    (another BLAS, or no /proc to find it in). The count is global: threads take turns, and
    a block may nest inside another of the same thread."""
    functions = _openblas_thread_functions()
    if functions is None:
        yield False
        return
    get, set_ = functions
    with _BLAS_LOCK:
        before = get()
        set_(1)
        try:
            yield True
        finally:
            set_(before)


_BLAS_LOCK = threading.RLock()
# OpenBLAS's names as numpy's wheels build it: "64_" for 64-bit integers, numpy 2's with a
# "scipy_" prefix.
_OPENBLAS_NAMES = [
    (f"{prefix}openblas_get_num_threads{suffix}", f"{prefix}openblas_set_num_threads{suffix}")
    for prefix in ("", "scipy_")
    for suffix in ("64_", "")
]


@functools.cache
def _openblas_thread_functions():
    """(get, set) of the thread count of the OpenBLAS loaded into this process, or None;
    numpy's own (its wheels' copy, under numpy.libs) first where others are loaded too."""
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower()}
    except OSError:
        return None
    paths = sorted(paths, key=lambda path: ("numpy" not in path, path))
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for get, set_ in _OPENBLAS_NAMES:
            if hasattr(lib, get) and hasattr(lib, set_):
                return getattr(lib, get), getattr(lib, set_)
    return None


def _too_many(where, key, asked: int, cores: int) -> int:
    warn_input(where, key, f"{asked} threads, this machine has {cores} cores: using {cores}")
    return cores


def _leading_count(text: str) -> int | None:
    """The first number of a thread variable ("8", or OpenMP's nested "8,2"), if any."""
    first = text.split(",")[0].strip()
    return int(first) if first.isdigit() and int(first) > 0 else None
