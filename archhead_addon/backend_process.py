"""The training backend as a child process, watched without blocking (for Blender's UI).

`BackendRun` starts `python -m archhead_addon.train ... --progress-json`; two reader threads
copy its stdout and stderr line by line into the log file and queue the JSON progress lines
(one object per line) for `poll()`, which never waits. `cancel()` sends SIGINT (the backend
saves a checkpoint and exits); `poll()` escalates to terminate and then kill if the process
outlives the grace time, so a caller that polls from a timer never blocks.
"""

from __future__ import annotations

import importlib.util
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from .track import FRAME_BUDGET

PACKAGE_ROOT = Path(__file__).resolve().parents[1]  # the folder that holds archhead_addon/
CANCEL_GRACE_S = 60.0  # SIGINT -> terminate -> kill, each after this long


def python_with_torch() -> str | None:
    """This process's Python when it can import torch (the bpy module installed in an
    environment with torch), else None: Blender's bundled Python has no torch."""
    return sys.executable if importlib.util.find_spec("torch") is not None else None


def train_command(
    python: str, data_dir, out_dir, config=None, resume: bool = False, minutes: float = 0.0
) -> list:
    """The training backend's command; `minutes`: its time limit (train/time_limit.py)."""
    cmd = [
        str(python),
        "-m",
        "archhead_addon.train",
        "--data",
        str(data_dir),
        "--out",
        str(out_dir),
        "--progress-json",
    ]
    if config:
        cmd += ["--config", str(config)]
    if resume:
        cmd.append("--resume")
    if minutes:
        cmd += ["--minutes", f"{minutes:.3f}"]
    return cmd


def track_command(
    python: str,
    source,
    out_dir,
    frames: int = 0,
    size: int = 512,
    photometric: bool = True,
    static_offset: bool = False,
    frame_budget: int = FRAME_BUDGET,
) -> list:
    """`frame_budget` 0: every frame (`track --frame-budget`)."""
    cmd = [str(python), "-m", "archhead_addon", "track", str(source), "--out", str(out_dir)]
    cmd += ["--size", str(size), "--frame-budget", str(frame_budget), "--progress-json"]
    cmd += [] if photometric else ["--no-photometric"]
    cmd += ["--static-offset"] if static_offset else []
    return cmd + (["--frames", str(frames)] if frames > 0 else [])


def format_eta(seconds) -> str:
    if seconds is None or not seconds >= 0:
        return "--:--"
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class BackendRun:
    """One backend process: `poll()` from a timer until `returncode` is set, then `close()`."""

    def __init__(self, command: list, log_path, cwd=None, grace: float = CANCEL_GRACE_S, env=None):
        """`env`: variables to set in the process's environment beyond this one's."""
        self.command = [str(c) for c in command]
        self.log_path = Path(log_path)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self.grace = grace
        self._log = open(self.log_path, "a", encoding="utf-8", buffering=1)
        self._log.write(f"$ {' '.join(self.command)}\n")
        self._lock = threading.Lock()
        self._records: queue.SimpleQueue = queue.SimpleQueue()
        extra_env, env = env, dict(os.environ)
        # the package shipped beside this file, whatever that Python's site-packages hold
        env["PYTHONPATH"] = os.pathsep.join(
            filter(None, [str(PACKAGE_ROOT), env.get("PYTHONPATH")])
        )
        env["PYTHONUNBUFFERED"] = "1"
        env.update(extra_env or {})
        self.process = subprocess.Popen(
            self.command,
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            encoding="utf-8",
            errors="replace",
            bufsize=1,
            start_new_session=True,
        )  # Ctrl-C in Blender's terminal is not the backend's
        self._readers = [
            threading.Thread(target=self._read, args=(stream, parse), daemon=True)
            for stream, parse in ((self.process.stdout, True), (self.process.stderr, False))
        ]
        for reader in self._readers:
            reader.start()
        self.last: dict = {}  # the latest progress record
        self.cancelled_at: float | None = None

    def _read(self, stream, parse: bool) -> None:
        for line in stream:
            with self._lock:
                if not self._log.closed:
                    self._log.write(line)
            if parse and line.lstrip().startswith("{"):
                try:
                    record = json.loads(line)
                except json.JSONDecodeError:
                    continue
                if isinstance(record, dict):
                    self._records.put(record)

    def poll(self) -> list[dict]:
        """Progress records that arrived since the last call; never blocks."""
        records = []
        while True:
            try:
                records.append(self._records.get_nowait())
            except queue.Empty:
                break
        if records:
            self.last = records[-1]
        self._escalate()
        return records

    @property
    def returncode(self) -> int | None:
        return self.process.poll()

    def cancel(self) -> None:
        """Ask the backend to stop cleanly (it saves a checkpoint on SIGINT)."""
        if self.cancelled_at is None and self.process.poll() is None:
            self.cancelled_at = time.monotonic()
            if os.name == "posix":
                self.process.send_signal(signal.SIGINT)
            else:  # Windows has no SIGINT for a child in another process group
                self.process.terminate()

    def _escalate(self) -> None:
        if self.cancelled_at is None or self.process.poll() is not None:
            return
        waited = time.monotonic() - self.cancelled_at
        if waited > 2 * self.grace:
            self.process.kill()
        elif waited > self.grace:
            self.process.terminate()

    def stop(self, timeout: float | None = None) -> int | None:
        """Cancel and wait for the exit (up to `timeout`, default the grace period: the
        backend finishes its step and saves), then terminate and close. For when nobody
        will poll any more: Blender quitting, the add-on disabled, another file loaded."""
        self.cancel()
        try:
            self.process.wait(self.grace if timeout is None else timeout)
        except subprocess.TimeoutExpired:
            self.process.terminate()
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if not self._log.closed:
            self.close()
        return self.process.returncode

    def close(self) -> None:
        """After the exit: drain the readers, note the exit code in the log, close it."""
        for reader in self._readers:
            reader.join(timeout=5.0)
        with self._lock:
            self._log.write(f"[exit code {self.process.returncode}]\n")
            self._log.close()
