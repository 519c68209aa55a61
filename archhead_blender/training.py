"""Train an avatar from Blender: the backend runs as a child process of the Python set in the
preferences (Blender's own Python never imports torch), watched by a modal operator whose
timer reads its JSON progress lines without blocking. Progress and ETA show in the N-panel
and the status bar; Cancel sends SIGINT (the backend saves), escalating if it must; the log
stays in the output folder; the finished checkpoint is loaded onto the head.
"""

from __future__ import annotations

import json
import time
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
from .preferences import get_preferences
from .avatar_objects import head_of, load_avatar
from .avatar_session import flame_model_path

AVATAR_FILE, LOG_FILE, REQUEST_FILE = "avatar.npz", "train.log", "train_request.json"
POLL_S = 0.5  # how often the timer reads the backend's progress
_run: dict = {"current": None}


class TrainingRun:
    """A started backend with what the interface shows about it."""

    def __init__(self, backend: BackendRun, out_dir: Path, head_name: str | None):
        self.backend, self.out_dir, self.head_name = backend, out_dir, head_name
        self.step = self.total = self.stage = 0
        self.seconds_per_step = self.eta = None
        self.loss: dict = {}
        self.error: str | None = None
        self.avatar = out_dir / AVATAR_FILE

    def update(self) -> bool:
        """Read new progress (train/progress.py's events); True once the process exited."""
        for record in self.backend.poll():
            event = record.get("event")
            if event == "step":
                self.step, self.total = int(record["step"]), int(record["total"])
                self.stage = record.get("stage", self.stage)
                self.seconds_per_step = record.get("seconds_per_step")
                self.eta = record.get("eta_seconds")
                self.loss = record.get("loss", {})
            elif event == "start":
                self.step, self.total = int(record["step"]), int(record["total"])
            elif event == "error":
                self.error = record.get("message")
            if "avatar" in record:
                self.avatar = Path(record["avatar"])
        return self.backend.returncode is not None

    @property
    def fraction(self) -> float:
        return self.step / self.total if self.total else 0.0

    def summary(self) -> str:
        if self.backend.cancelled_at is not None:
            return "Stopping (saving a checkpoint) ..."
        if not self.total:
            return "Starting ..."
        rate = f", {self.seconds_per_step:.2f} s/step" if self.seconds_per_step else ""
        return (f"Stage {self.stage}: {self.step} / {self.total}{rate}, "
                f"ETA {format_eta(self.eta)}")

    def loss_text(self) -> str:
        if not self.loss:
            return ""
        total = self.loss.get("total")
        terms = ", ".join(f"{k} {v:.4g}" for k, v in self.loss.items() if k != "total")
        return f"loss {total:.4g} ({terms})" if total is not None else terms


def current_run() -> TrainingRun | None:
    return _run["current"]


def backend_python(context) -> str:
    """The preferences' Python, else this process's Python when it has torch (the bpy module
    in the project's environment); Blender's bundled Python has none."""
    prefs = get_preferences(context)
    if prefs and prefs.backend_python:
        return bpy.path.abspath(prefs.backend_python)
    python = python_with_torch()
    if python is not None:
        return python
    raise ValueError("set 'Backend Python' in ArchHead's preferences to the Python of an "
                     "environment with torch")


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
    for name, target in (("frames", frames_dir), ("masks", source / "masks"),
                         ("parts", source / "parts")):
        link = data / name
        if link.is_symlink():
            link.unlink()
        if target.is_dir() and not link.exists():
            link.symlink_to(target, target_is_directory=True)
    write_canonical(read_sequence(tracking), data / "tracking.npz")
    return data


def start_training(context, frames_dir, tracking, out_dir, settings: dict,
                   resume: bool = False, head_name: str | None = None) -> TrainingRun:
    """Write the config, launch the backend, remember the run for the panel."""
    if current_run() is not None:
        raise ValueError("a training run is already going; cancel it first")
    out_dir = Path(out_dir).resolve()
    data = prepare_data(frames_dir, tracking, out_dir)
    config = out_dir / REQUEST_FILE
    config.write_text(json.dumps(settings, indent=1) + "\n")
    command = train_command(backend_python(context), data, out_dir, config, resume)
    model = flame_model_path(context)
    if model:
        command += ["--flame", bpy.path.abspath(model)]
    backend = BackendRun(command, out_dir / LOG_FILE)
    _run["current"] = run = TrainingRun(backend, out_dir, head_name)
    return run


def finish_training(context, run: TrainingRun) -> tuple[str, str]:
    """Close the run; load its checkpoint onto the head. Returns (report type, message)."""
    _run["current"] = None
    run.update()
    run.backend.close()
    code = run.backend.returncode
    checkpoint = run.avatar
    cancelled = run.backend.cancelled_at is not None
    if code != 0 and not (cancelled and checkpoint.is_file()):
        reason = run.error or f"exit code {code}"
        return "ERROR", f"training failed ({reason}); see {run.out_dir / LOG_FILE}"
    head = bpy.data.objects.get(run.head_name) if run.head_name else None
    if head is not None and checkpoint.is_file():
        load_avatar(context, head, checkpoint)
        return "INFO", f"{'Stopped' if cancelled else 'Trained'}: {checkpoint} loaded"
    return "INFO", f"{'Stopped' if cancelled else 'Trained'}: {checkpoint}"
