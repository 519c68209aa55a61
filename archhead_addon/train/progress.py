"""Progress of a training run: a bar for people (stderr) and JSON lines for programs (stdout).

The event schema lives here for both sides: `Progress` writes it, `RunStatus` reads it (the
Blender operator, through the backend's stdout). JSON events, one object per line, flushed at
once:
  {"event": "start", "step": 0, "total": 1500, "device": "cpu", "renderer": "cpu", ...}
  {"event": "step", "stage": 1, "step": 12, "total": 1500, "loss": {"rgb": ..., "total": ...},
   "lods": [0.0], "seconds_per_step": 1.9, "eta_seconds": 2800.0, "elapsed_seconds": 23.1}
  {"event": "checkpoint", "step": 100, "avatar": "OUT/avatar.npz"}
  {"event": "done" | "interrupted", "step": 1500, "avatar": "OUT/avatar.npz", ...}
  {"event": "error", "message": "..."}
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field

START, STEP, CHECKPOINT, DONE, INTERRUPTED, ERROR = (
    "start",
    "step",
    "checkpoint",
    "done",
    "interrupted",
    "error",
)
BAR_WIDTH = 24
LINES_WITHOUT_TTY = 100  # a non-terminal stderr (a log file) gets about this many lines a run


@dataclass
class StepReport:
    stage: int
    step: int  # steps done, 1..total
    total: int
    loss: dict  # unweighted terms and the total, averaged over the step's levels
    lods: list
    seconds_per_step: float
    eta_seconds: float
    elapsed_seconds: float

    def to_json(self) -> dict:
        return {
            "event": STEP,
            "stage": self.stage,
            "step": self.step,
            "total": self.total,
            "loss": {k: round(v, 6) for k, v in self.loss.items()},
            "lods": [round(lod, 4) for lod in self.lods],
            "seconds_per_step": round(self.seconds_per_step, 4),
            "eta_seconds": round(self.eta_seconds, 1),
            "elapsed_seconds": round(self.elapsed_seconds, 1),
        }


def format_seconds(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class Progress:
    def __init__(self, json_lines: bool):
        self.json_lines = json_lines
        self.out, self.err = sys.stdout, sys.stderr
        self.tty = self.err.isatty()
        self._last_line = 0.0

    def _json(self, record: dict) -> None:
        if self.json_lines:
            self.out.write(json.dumps(record) + "\n")
            self.out.flush()

    def event(self, kind: str, **fields) -> None:
        self._json({"event": kind, **fields})

    def step(self, report: StepReport) -> None:
        self._json(report.to_json())
        every = max(1, report.total // LINES_WITHOUT_TTY)
        if self.tty:
            if time.monotonic() - self._last_line > 0.1 or report.step == report.total:
                self._last_line = time.monotonic()
                self.err.write("\r" + self.bar(report) + "\x1b[K")  # erase the old line's rest
                self.err.flush()
        elif report.step % every == 0 or report.step == report.total:
            self.err.write(self.bar(report) + "\n")
            self.err.flush()

    def checkpoint(self, step: int, avatar) -> None:
        self.event(CHECKPOINT, step=step, avatar=str(avatar))

    def message(self, text: str) -> None:
        """A line for people (stderr), after the bar's line if one is showing."""
        self.err.write(("\n" if self.tty and self._last_line else "") + text + "\n")
        self.err.flush()
        self._last_line = 0.0

    @staticmethod
    def bar(r: StepReport) -> str:
        filled = BAR_WIDTH * r.step // r.total
        return (
            f"stage {r.stage} [{'#' * filled}{'.' * (BAR_WIDTH - filled)}] "
            f"{r.step}/{r.total}  rgb {r.loss['rgb']:.5f}  {r.seconds_per_step:.2f} s/step"
            f"  ETA {format_seconds(r.eta_seconds)}"
        )


@dataclass
class RunStatus:
    """What a reader of the JSON lines knows about the run so far."""

    step: int = 0
    total: int = 0
    stage: int = 0
    loss: dict = field(default_factory=dict)
    seconds_per_step: float | None = None
    eta_seconds: float | None = None
    error: str | None = None
    avatar: str | None = None  # the latest checkpoint written

    def apply(self, record: dict) -> None:
        """Take in one event (unknown events and keys are ignored: newer backends)."""
        event = record.get("event")
        if event in (START, STEP):
            self.step, self.total = int(record["step"]), int(record["total"])
        if event == STEP:
            self.stage = record.get("stage", self.stage)
            self.seconds_per_step = record.get("seconds_per_step")
            self.eta_seconds = record.get("eta_seconds")
            self.loss = record.get("loss", {})
        elif event == ERROR:
            self.error = record.get("message")
        if "avatar" in record:
            self.avatar = record["avatar"]
