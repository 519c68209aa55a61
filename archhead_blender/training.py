"""Train an avatar from Blender: the backend runs as a child process of the Python set in the
preferences (Blender's own Python never imports torch), watched by the Train operator's timer,
which reads its JSON progress lines (train/progress.py's schema) without blocking. Cancel
sends SIGINT (the backend saves), escalating if it must; the log stays in the output folder;
the finished checkpoint is loaded onto the head.

Settings start from the same preset as the command line (train/config.py DEFAULT_PRESET, or a
base config file) and the operator overrides only what the user changed.
"""

from __future__ import annotations

import json
from pathlib import Path

import bpy

from archhead_addon.backend_process import (
    BackendRun,
    format_eta,
    python_with_torch,
    train_command,
)
from archhead_addon.io.errors import InputError
from archhead_addon.sequences import read_sequence, write_canonical
from archhead_addon.train.config import DEFAULT_PRESET, config_data
from archhead_addon.train.progress import RunStatus
from archhead_addon.train.run_folder import RunFolder

from .avatar_objects import load_avatar
from .avatar_session import flame_model_path
from .preferences import get_preferences
from .state import STATE

POLL_S = 0.5  # how often the timer reads the backend's progress


def training_settings(overrides: dict, base_config: str = "") -> dict:
    """The config the backend gets: the base config file (default: the command line's
    preset) with `overrides` on top, key by key."""
    settings = config_data(base_config or DEFAULT_PRESET)  # InputError names the file
    settings.update(overrides)
    return settings


class TrainingRun:
    """A started backend with what the interface shows about it."""

    def __init__(self, backend: BackendRun, out_dir: Path, head_name: str | None):
        self.backend, self.out_dir, self.head_name = backend, out_dir, head_name
        self.run_folder = RunFolder(out_dir)
        self.status = RunStatus()
        # how to go on after a stop, after "To go on: " (Avatar from Video has its own)
        self.resume_hint = (
            "Train Avatar with the same frames, tracking and Output, and Resume ticked"
        )

    def update(self) -> bool:
        """Read new progress events; True once the process exited."""
        for record in self.backend.poll():
            self.status.apply(record)
        return self.backend.returncode is not None

    @property
    def step(self) -> int:
        return self.status.step

    @property
    def avatar(self) -> Path:
        return Path(self.status.avatar) if self.status.avatar else self.run_folder.avatar

    @property
    def fraction(self) -> float:
        return self.status.step / self.status.total if self.status.total else 0.0

    def summary(self) -> str:
        s = self.status
        if self.backend.cancelled_at is not None:
            return "Stopping (saving a checkpoint) ..."
        if not s.total:
            return "Starting ..."
        rate = f", {s.seconds_per_step:.2f} s/step" if s.seconds_per_step else ""
        return f"Stage {s.stage}: {s.step} / {s.total}{rate}, ETA {format_eta(s.eta_seconds)}"

    def stop_unwatched(self) -> str:
        """Stop the run when nothing will watch it any more (Blender quitting, the add-on
        disabled, another file loaded): wait while the backend saves its checkpoint, then say
        where the run stands and how to go on, in the console and at the end of its log
        (Blender's window, and with it the status bar, is gone by then)."""
        self.backend.stop()
        self.update()
        message = self.stopped_message()
        print(f"ArchHead: {message}", flush=True)
        with open(self.run_folder.log, "a", encoding="utf-8") as log:
            log.write(f"ArchHead: {message}\n")
        return message

    def stopped_message(self) -> str:
        code, s = self.backend.returncode, self.status
        if code == 0:
            return f"training finished; the avatar is {self.avatar}"
        if self.avatar.is_file():
            return (
                f"training stopped at step {s.step} of {s.total}; its checkpoint is saved in "
                f"{self.out_dir}. To go on: {self.resume_hint}"
            )
        return f"training stopped (exit code {code}) before a checkpoint; see {self.run_folder.log}"

    # The sidebar's Training box: at the default sidebar width a line holds about 32
    # characters; summary() (the status bar's) and loss_text() were cut there.
    def bar_text(self) -> str:
        """The progress bar's text in the sidebar: the stage and step alone."""
        s = self.status
        if self.backend.cancelled_at is not None:
            return "Stopping (saving) ..."
        if not s.total:
            return "Starting ..."
        return f"Stage {s.stage}: {s.step:,} / {s.total:,}"

    def rate_text(self) -> str:
        """Speed and time left, under the bar ("" before the first step)."""
        s = self.status
        if not s.total or self.backend.cancelled_at is not None:
            return ""
        rate = f"{s.seconds_per_step:.2f} s/step, " if s.seconds_per_step else ""
        return f"{rate}ETA {format_eta(s.eta_seconds)}"

    def loss_lines(self, per_line: int = 2) -> list[str]:
        """The loss for the sidebar: the total on a line, then its terms, `per_line` a line."""
        loss = self.status.loss
        if not loss:
            return []
        lines = [f"Loss {loss['total']:.4g}"] if loss.get("total") is not None else []
        terms = [f"{k} {v:.3g}" for k, v in loss.items() if k != "total"]
        for start in range(0, len(terms), per_line):
            lines.append(", ".join(terms[start : start + per_line]))
        return lines

    def loss_text(self) -> str:
        loss = self.status.loss
        if not loss:
            return ""
        total = loss.get("total")
        terms = ", ".join(f"{k} {v:.4g}" for k, v in loss.items() if k != "total")
        return f"loss {total:.4g} ({terms})" if total is not None else terms


def current_run() -> TrainingRun | None:
    return STATE.training_run


def backend_python(context) -> str:
    """The preferences' Python, else this process's Python when it has torch (the bpy module
    in the project's environment); Blender's bundled Python has none."""
    prefs = get_preferences(context)
    if prefs and prefs.backend_python:
        return bpy.path.abspath(prefs.backend_python)
    python = python_with_torch()
    if python is not None:
        return python
    raise ValueError(
        "set 'Backend Python' in ArchHead's preferences to the Python of an environment with torch"
    )


def prepare_data(frames_dir, tracking, out_dir) -> Path:
    """The backend's data folder (DATA/frames, DATA/tracking.npz, optional masks/ and parts/
    beside frames/). When the picks already form one, it is used as it is; otherwise
    OUT/data links the frames folder and holds the tracking converted to the canonical npz."""
    frames_dir, tracking = Path(frames_dir).resolve(), Path(tracking).resolve()
    if not frames_dir.is_dir():
        raise InputError(frames_dir, None, "frames folder not found")
    source = frames_dir.parent
    if frames_dir.name == "frames" and tracking == source / "tracking.npz":
        return source
    data = Path(out_dir) / "data"
    data.mkdir(parents=True, exist_ok=True)
    for name, target in (
        ("frames", frames_dir),
        ("masks", source / "masks"),
        ("parts", source / "parts"),
    ):
        link = data / name
        if link.is_symlink():
            link.unlink()
        if target.is_dir() and not link.exists():
            link.symlink_to(target, target_is_directory=True)
    write_canonical(read_sequence(tracking), data / "tracking.npz")
    return data


def start_training(
    context,
    frames_dir,
    tracking,
    out_dir,
    settings: dict,
    resume: bool = False,
    head_name: str | None = None,
    env: dict | None = None,
    minutes: float = 0.0,
) -> TrainingRun:
    """Write the config, launch the backend, remember the run for the panel. `env`:
    variables for the backend's environment (BackendRun); `minutes`: the run's time limit
    from now (0: none), its steps shortened to fit (train/time_limit.py)."""
    if current_run() is not None:
        raise ValueError("a training run is already going; cancel it first")
    out_dir = Path(out_dir).resolve()
    data = prepare_data(frames_dir, tracking, out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)  # the run's request and log go in first
    run_folder = RunFolder(out_dir)
    config = run_folder.request
    config.write_text(json.dumps(settings, indent=1) + "\n")
    command = train_command(backend_python(context), data, out_dir, config, resume, minutes)
    model = flame_model_path(context)
    if model:
        command += ["--flame", bpy.path.abspath(model)]
    backend = BackendRun(command, run_folder.log, env=env)
    STATE.training_run = run = TrainingRun(backend, out_dir, head_name)
    return run


def finish_training(context, run: TrainingRun) -> tuple[str, str]:
    """Close the run; load its checkpoint onto the head. Returns (report type, message)."""
    STATE.training_run = None
    run.update()
    run.backend.close()
    code = run.backend.returncode
    checkpoint = run.avatar
    cancelled = run.backend.cancelled_at is not None
    if code != 0 and not (cancelled and checkpoint.is_file()):
        reason = run.status.error or f"exit code {code}"
        return "ERROR", f"training failed ({reason}); see {run.run_folder.log}"
    head = bpy.data.objects.get(run.head_name) if run.head_name else None
    if head is not None and checkpoint.is_file():
        load_avatar(context, head, checkpoint)
        return "INFO", f"{'Stopped' if cancelled else 'Trained'}: {checkpoint} loaded"
    return "INFO", f"{'Stopped' if cancelled else 'Trained'}: {checkpoint}"
