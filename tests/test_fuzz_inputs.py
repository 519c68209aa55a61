"""Every reader against the fuzz corpus (tests/fuzz_corpus.py): over 100 malformed files
each, no raw traceback, no read over the time limit, no allocation far above the input's
size, no NaN or Inf in a result, no code run from a file; checkpoints, cache frames and
training states, which carry a checksum, never come back changed."""

from collections import Counter

import pytest
from fuzz_corpus import corpus, run, table


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    return run(corpus(root), root)


def test_every_reader_meets_the_aims(results):
    print("\n" + table(results))
    files = Counter(r["reader"] for r in results if r["label"] != "seed")
    assert len(files) == 15 and min(files.values()) >= 100, files
    bad = [r for r in results if r["outcome"] in ("raw", "hang", "alloc", "nonfinite", "code")]
    assert not bad, "\n".join(
        f"{r['reader']} | {r['label']} | {r['outcome']} | {r['detail']}" for r in bad
    )


def test_seeds_read_cleanly(results):
    seeds = {r["reader"]: r["outcome"] for r in results if r["label"] == "seed"}
    assert set(seeds.values()) <= {"same"}, [
        r for r in results if r["label"] == "seed" and r["outcome"] != "same"
    ]


def test_checksummed_files_never_come_back_changed(results):
    changed = [
        r["label"]
        for r in results
        if r["reader"] in ("avatar checkpoint", "decode cache", "train_state")
        and r["outcome"] == "changed"
    ]
    assert not changed


CRAFTED = ("3 GiB", "6D", "model weight", "optimizer exp_avg")
"""Labels of cases crafted for issue 33: files declaring 3 GiB (refused before anything is
inflated or allocated: tests/test_size_bombs.py measures their memory), degenerate 6D
rotations, training states with weights or Adam moments past state_file's limits."""


def test_crafted_cases_are_refused(results):
    crafted = [r for r in results if any(k in r["label"] for k in CRAFTED)]
    # 6 per torch.save reader (3), 4 per npz reader (7; the vhap folder takes every other
    # one), 3 rotations, 6 training states
    assert len(crafted) == 3 * 6 + 7 * 4 + 2 + 3 + 6, len(crafted)
    assert all(r["outcome"] == "error" for r in crafted), [
        (r["reader"], r["label"], r["outcome"]) for r in crafted if r["outcome"] != "error"
    ]


def test_heldout_kinds(results):
    """Issue 33's held-out corpus: each kind of file it found mishandled, and legal layouts
    (npy 2.0, Fortran order, big-endian, deflated, data descriptors, zip64, pickle protocol
    5, OrderedDicts, scipy.sparse), refused ("held-out error:") or read as the seed is
    ("held-out same:")."""
    held = [r for r in results if "held-out " in r["label"]]
    assert len(held) >= 100, len(held)
    wrong = [
        (r["reader"], r["label"], r["outcome"], r["detail"])
        for r in held
        if r["outcome"] != r["label"].split("held-out ")[1].split(":")[0]
    ]
    assert not wrong, wrong
