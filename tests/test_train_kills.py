"""A run killed at any moment, above all during its last checkpoint, leaves files that resume
brings into agreement: avatar.npz holds train_state.pt's weights, config.json its config,
checkpoint.json vouches for all three, no temporary file is left, and no more than one
checkpoint interval of steps is lost. Kills are simulated in-process (an exception no except
clause catches, leaving the temporary file a SIGKILL would); the real SIGKILL is in
test_train_resume.py.

    pytest tests/test_train_kills.py -s     # prints the figures of docs/training.md
"""

import json
import os
import shutil
import sys

import numpy as np
import pytest
from training_subject import write_config

from archhead_addon.avatar.checkpoint_format import read_checkpoint
from archhead_addon.avatar.decode_cache import STALE_TMP_S, DiskCache
from archhead_addon.io import atomic
from archhead_addon.train import loop
from archhead_addon.train.__main__ import main
from archhead_addon.train.loop import load_state
from archhead_addon.train.run_folder import RunFolder

EVERY, TOTAL = 2, 6  # checkpoints at steps 2, 4 and 6
KILLS = 25


class Killed(BaseException):
    """A simulated SIGKILL: nothing catches it and nothing after it runs."""


class _KillingOs:
    """`os` for io/atomic.py that records the targets of its renames and kills the process at
    rename number `at` (from 0; None: never), before it or, with `after`, just after it."""

    def __init__(self, at: int | None, after: bool = False):
        self.at, self.after, self.targets = at, after, []

    def __getattr__(self, name):
        return getattr(os, name)

    def replace(self, src, dst):
        self.targets.append(os.fspath(dst))
        if len(self.targets) - 1 != self.at:
            return os.replace(src, dst)
        if self.after:
            os.replace(src, dst)
        else:  # a kill skips the `finally` that deletes the temporary file: keep a copy
            shutil.copy(src, f"{src}.killed.tmp")
        raise Killed


@pytest.fixture(scope="module")
def subject(tiny_subject):
    return tiny_subject


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    folder = tmp_path_factory.mktemp("kills")
    return write_config(
        folder / "c.json", stage1_steps=TOTAL - 2, stage2_steps=2, checkpoint_every=EVERY
    )


def train(subject, out, *extra) -> int:
    return main(["--data", str(subject), "--out", str(out), "--progress-json", *extra])


def events(capsys) -> list[dict]:
    return [json.loads(line) for line in capsys.readouterr().out.splitlines()]


def renames_in_a_run(subject, config, out, capsys) -> tuple[int, int]:
    """(renames in a whole run, renames of its last checkpoint), counted on a clean run."""
    recorder = _KillingOs(at=None)
    with pytest.MonkeyPatch.context() as m:
        m.setattr(atomic, "os", recorder)
        assert train(subject, out, "--config", str(config)) == 0
    capsys.readouterr()
    targets = recorder.targets
    last = len(targets) - 1 - targets[::-1].index(os.fspath(RunFolder(out).state))
    return len(targets), len(targets) - last


def killed_run(subject, config, out, capsys, at: int, after: bool = False, step=None) -> int:
    """Run until the kill (a rename `at`, or during step `step` + 1); the steps done."""
    with pytest.MonkeyPatch.context() as m:
        if step is None:
            m.setattr(atomic, "os", _KillingOs(at, after))
        else:
            train_step = loop.Trainer.train_step

            def dying_step(self):
                if self.step == step:
                    raise Killed
                return train_step(self)

            m.setattr(loop.Trainer, "train_step", dying_step)
        with pytest.raises(Killed):
            train(subject, out, "--config", str(config))
    return max((e["step"] for e in events(capsys) if e["event"] == "step"), default=0)


def finish(subject, config, out, capsys) -> int:
    """Resume (or, with no state written yet, start again) to the end; the first step."""
    run = RunFolder(out)
    extra = ["--resume"] if run.state.is_file() else ["--config", str(config)]
    assert train(subject, out, *extra) == 0
    seen = events(capsys)
    assert seen[-1]["event"] == "done" and seen[-1]["step"] == TOTAL
    return seen[0]["step"]


def disagreements(run: RunFolder) -> list[str]:
    """What differs between the run's files, checked from their contents (not the manifest
    alone): the avatar's weights against the state's, the config, the step, stray files."""
    found = run.problems()
    state = load_state(run.state)
    ckpt = read_checkpoint(run.avatar)
    weights = state["model"]
    found += [
        f"avatar {name}"
        for name, value in ckpt.params.items()
        if not np.array_equal(value, weights[name].numpy())
    ]
    if not np.array_equal(ckpt.identity_shape, weights["identity_shape"].numpy()):
        found.append("avatar identity_shape")
    if json.loads(run.config.read_text()) != json.loads(state["config"]):
        found.append("config.json")
    if state["step"] != TOTAL:
        found.append(f"state at step {state['step']}")
    found += [f"left behind: {p.name}" for p in run.root.glob(".*.tmp")]
    return found


def test_kills_at_every_write_and_at_random_moments(subject, config, tmp_path, capsys):
    renames, last_checkpoint = renames_in_a_run(subject, config, tmp_path / "clean", capsys)
    assert last_checkpoint == 3  # state, avatar, manifest (config.json unchanged: not rewritten)
    kills = [(at, False, None) for at in range(renames)]  # before every rename of the run
    kills.append((renames - 1, True, None))  # after the last: killed before saying "done"
    rng = np.random.default_rng(18)
    while len(kills) < KILLS:  # random moments: a rename, or in the middle of a step
        if rng.random() < 0.5:
            kills.append((int(rng.integers(renames)), bool(rng.random() < 0.5), None))
        else:
            kills.append((None, False, int(rng.integers(TOTAL))))

    disagreeing, lost = [], []
    for i, (at, after, step) in enumerate(kills):
        out = tmp_path / f"run{i}"
        done = killed_run(subject, config, out, capsys, at, after, step)
        restarted = finish(subject, config, out, capsys)
        lost.append(done - restarted)
        if found := disagreements(RunFolder(out)):
            disagreeing.append((at, after, step, found))
    print(
        f"\n{len(kills)} kills ({renames + 1} at every write, {last_checkpoint + 1} of them in "
        f"the last checkpoint): {len(disagreeing)} runs whose files disagree after resume; "
        f"steps lost at most {max(lost)} (checkpoint_every {EVERY})",
        file=sys.stderr,
    )
    assert not disagreeing
    assert max(lost) <= EVERY


def test_a_lagging_avatar_is_rewritten_and_named(subject, config, tmp_path, capsys):
    """The issue's case: killed after the final train_state.pt, before avatar.npz."""
    out = tmp_path / "run"
    renames, _ = renames_in_a_run(subject, config, tmp_path / "clean", capsys)
    killed_run(subject, config, out, capsys, at=renames - 2)  # the final avatar's rename
    run = RunFolder(out)
    assert load_state(run.state)["step"] == TOTAL
    assert f"avatar.npz is of step {TOTAL - EVERY}, train_state.pt of {TOTAL}" in (
        run.problems(TOTAL)
    )
    assert train(subject, out, "--resume") == 0
    assert f"repaired: avatar.npz is of step {TOTAL - EVERY}, train_state.pt of {TOTAL}" in (
        capsys.readouterr().err
    )
    assert not disagreements(run)


def test_exit_0_only_with_the_promised_files(subject, config, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(RunFolder, "write_manifest", lambda self, step, total: None)
    assert train(subject, tmp_path / "run", "--config", str(config)) == 1
    last = events(capsys)[-1]
    assert last["event"] == "error" and "checkpoint.json is missing" in last["message"]


def test_stale_temporaries_go_when_a_run_or_a_cache_is_opened(subject, config, tmp_path):
    run = RunFolder(tmp_path / "run")
    run.root.mkdir()
    stale = run.root / ".avatar.npz.k1ll3d.tmp"
    stale.write_bytes(b"torn")
    assert train(subject, run.root, "--config", str(config)) == 0
    assert not stale.exists()

    cache = tmp_path / "cache"
    cache.mkdir()
    old, fresh = cache / ".frame.npz.aaaa.tmp", cache / ".frame.npz.bbbb.tmp"
    for path in (old, fresh):
        path.write_bytes(b"")
    os.utime(old, (0, 0))  # another machine may be writing `fresh` right now
    DiskCache(cache)
    assert not old.exists() and fresh.exists()
    assert STALE_TMP_S >= 60
