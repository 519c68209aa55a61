"""Crafted files of about 3 MB that declare 3 GiB (tests/fuzz_corpus.py `torch_size_bombs`,
`npz_size_bombs`: a storage or npy member deflated from 3 GiB of zeros, a directory that
understates or overstates a member, a pickle or an npy header that claims 3 GiB), each read
by its reader in a fresh process: every one refused with an InputError, the process's peak
resident memory under issue 33's 512 MB. Peak memory does not depend on the machine's load,
so it is asserted; the time of each read is printed, not asserted (the corpus test's 5 s
limit covers it). Before the fix a storage member inflating to 3 GiB behind a directory
that declared 3 MB was read at 2.1 GB peak, and a stored npy member claiming 3 GiB was
refused after a 3 GiB allocation (3.1 GB peak)."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fuzz_corpus import (
    _clip,
    _metrical_frame,
    npz_size_bombs,
    torch_bytes,
    torch_size_bombs,
)

PEAK_LIMIT_MB = 512

# Reads each file named on the command line with one reader, printing one JSON line each:
# the outcome, the seconds taken and the process's peak resident memory so far (MB: Linux's
# VmHWM, else ru_maxrss, which on Linux starts at the pytest process's own peak).
CHILD = """
import json, resource, sys, time
sys.path[:0] = [sys.argv[1], sys.argv[2]]
from fuzz_corpus import _reader
from archhead_addon.io.errors import InputError
read = _reader(sys.argv[3])
for path in sys.argv[4:]:
    start = time.perf_counter()
    try:
        read(path)
        outcome = "read"
    except InputError as exc:
        outcome = "InputError: " + str(exc)[:200]
    except BaseException as exc:
        outcome = type(exc).__name__ + ": " + str(exc)[:200]
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    try:  # the process's own peak: ru_maxrss keeps the parent's across fork and exec
        with open("/proc/self/status") as status:
            hwm = [line for line in status if line.startswith("VmHWM:")]
        peak = int(hwm[0].split()[1]) / 1024
    except (OSError, IndexError, ValueError):
        pass
    print(json.dumps({"path": path, "outcome": outcome, "seconds": seconds, "peak_mb": peak}))
"""


def _cases():
    clip = _clip()
    npz_clip = {**clip, "fps": np.float64(clip["fps"])}
    return {
        "driving clip .pt": ("c.pt", torch_size_bombs(torch_bytes(clip))),
        "metrical .frame": ("00001.frame", torch_size_bombs(torch_bytes(_metrical_frame()))),
        "driving clip npz": ("c.npz", npz_size_bombs(npz_clip)),
    }


@pytest.mark.parametrize("reader", ["driving clip .pt", "metrical .frame", "driving clip npz"])
def test_files_declaring_3_gib_are_refused_in_bounded_memory(tmp_path, reader):
    name, cases = _cases()[reader]
    paths, labels = [], {}
    for i, (label, data) in enumerate(cases):
        assert len(data) < 4 << 20  # small files: at most 4 MB each
        path = tmp_path / str(i) / name
        path.parent.mkdir()
        path.write_bytes(data)
        paths.append(str(path))
        labels[str(path)] = label
    tests = Path(__file__).parent
    run = subprocess.run(
        [sys.executable, "-c", CHILD, str(tests), str(tests.parent), reader, *paths],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [json.loads(line) for line in run.stdout.splitlines()]
    assert len(rows) == len(paths)
    for row in rows:
        label = labels[row["path"]]
        print(f"{reader} | {label} | {row['seconds']:.2f} s | peak {row['peak_mb']:.0f} MB")
        assert row["outcome"].startswith("InputError: "), (label, row["outcome"])
        assert row["peak_mb"] < PEAK_LIMIT_MB, (label, row)
