"""The training command line as a process: kill -9 mid-run loses only the steps since the
last checkpoint and --resume finishes the run; Ctrl-C saves and exits cleanly."""

import json
import signal
import subprocess
import sys

import pytest
from training_subject import REPO_ROOT, write_config

from archhead_addon.avatar.runtime import AvatarRuntime
from archhead_addon.train.loop import load_state
from archhead_addon.train.run_folder import RunFolder

TOTAL = 40


def command(tiny_subject, out, *extra):
    return [
        sys.executable,
        "-m",
        "archhead_addon.train",
        "--data",
        str(tiny_subject),
        "--out",
        str(out),
        "--progress-json",
        *extra,
    ]


def start(cmd):
    return subprocess.Popen(
        cmd, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def events_until(proc, done) -> list[dict]:
    """Read events until done(event) is true; fails if the process ends first."""
    events = []
    for line in proc.stdout:
        events.append(json.loads(line))
        if done(events[-1]):
            return events
    pytest.fail(f"the run ended early: {proc.wait()} {proc.stderr.read()}")


def test_kill_9_then_resume_continues_from_the_last_checkpoint(tiny_subject, tmp_path):
    config = write_config(
        tmp_path / "c.json", stage1_steps=TOTAL - 10, stage2_steps=10, checkpoint_every=3
    )
    out = tmp_path / "run"
    proc = start(command(tiny_subject, out, "--config", str(config)))
    try:
        seen = events_until(proc, lambda e: e["event"] == "checkpoint" and e["step"] >= 6)
        seen += events_until(proc, lambda e: e["event"] == "step")  # past the checkpoint
    finally:
        proc.kill()  # SIGKILL, wherever it is: mid-step or writing the next checkpoint
        proc.wait()
    killed_at = seen[-1]["step"]
    state = load_state(RunFolder(out).state)
    assert state["step"] % 3 == 0 and killed_at - 3 <= state["step"] <= killed_at
    AvatarRuntime.load(RunFolder(out).avatar).decode(0.0)  # the checkpoint is whole

    done = subprocess.run(
        command(tiny_subject, out, "--resume"),
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    events = [json.loads(line) for line in done.stdout.splitlines()]
    assert events[0]["event"] == "start" and events[0]["step"] == state["step"]
    steps = [e["step"] for e in events if e["event"] == "step"]
    assert steps == list(range(state["step"] + 1, TOTAL + 1))
    assert events[-1]["event"] == "done" and load_state(RunFolder(out).state)["step"] == TOTAL
    assert "resumed at step" in done.stderr


def test_ctrl_c_saves_and_exits(tiny_subject, tmp_path):
    config = write_config(
        tmp_path / "c.json", stage1_steps=TOTAL, stage2_steps=0, checkpoint_every=1000
    )
    out = tmp_path / "run"
    proc = start(command(tiny_subject, out, "--config", str(config)))
    try:
        events_until(proc, lambda e: e["event"] == "step" and e["step"] >= 2)
        proc.send_signal(signal.SIGINT)
        rest, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    events = [json.loads(line) for line in rest.splitlines()]
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    last = events[-1]
    assert last["event"] == "interrupted" and 2 <= last["step"] < TOTAL
    assert events[-2] == {
        "event": "checkpoint",
        "step": last["step"],
        "avatar": str(RunFolder(out).avatar),
    }
    assert load_state(RunFolder(out).state)["step"] == last["step"]
    AvatarRuntime.load(RunFolder(out).avatar).decode(1.0)
