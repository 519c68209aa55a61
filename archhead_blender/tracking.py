"""Track a video from Blender: `python -m archhead_addon track` runs as a child process of the
backend Python (as training does; Blender's Python has neither torch nor mediapipe), watched
by the Track Video operator's timer through its JSON progress lines. When it finishes, the
tracked sequence is imported as a rigged head; the training folder stays for Train Avatar.
"""

from __future__ import annotations

from pathlib import Path

import bpy

from archhead_addon.backend_process import BackendRun, track_command
from archhead_addon.track import FRAME_BUDGET
from archhead_addon.train.dataset import TRACKING_FILE
from archhead_addon.train.progress import RunStatus

from .avatar_session import flame_model_path
from .importing import import_sequence
from .state import STATE
from .training import backend_python

# in the order the backend reports them (archhead_addon.track.pipeline); "refine" only with
# the photometric refinement, "masks" (the head-and-neck masks) last in every run
STAGES = ("detect", "fit", "write", "refine", "masks")
LOG_NAME = "track.log"  # beside the output folder: the folder itself appears only at the end


class TrackingRun:
    def __init__(self, backend: BackendRun, out_dir: Path, log: Path):
        self.backend, self.out_dir, self.log = backend, out_dir, log
        self.status = RunStatus()

    def update(self) -> bool:
        for record in self.backend.poll():
            self.status.apply(record)
        return self.backend.returncode is not None

    @property
    def fraction(self) -> float:
        """Progress over the stages, an equal share each."""
        s = self.status
        if s.stage not in STAGES or not s.total:
            return 0.0
        return (STAGES.index(s.stage) + s.step / s.total) / len(STAGES)

    def summary(self) -> str:
        s = self.status
        if self.backend.cancelled_at is not None:
            return "Stopping ..."
        if s.stage not in STAGES:
            return "Starting ..."
        return f"{s.stage.capitalize()}: {s.step} / {s.total}"


def current_tracking() -> TrackingRun | None:
    return STATE.tracking_run


def start_tracking(
    context,
    source,
    out_dir,
    frames: int = 0,
    size: int = 512,
    photometric: bool = True,
    static_offset: bool = False,
    env: dict | None = None,
    frame_budget: int = FRAME_BUDGET,
) -> TrackingRun:
    """`env`: variables for the backend's environment (BackendRun); `frame_budget` 0: every
    frame."""
    if current_tracking() is not None:
        raise ValueError("a tracking run is already going; cancel it first")
    source, out_dir = Path(source).resolve(), Path(out_dir).resolve()
    if not source.exists():
        raise ValueError(f"{source}: not found")
    command = track_command(
        backend_python(context),
        source,
        out_dir,
        frames,
        size,
        photometric,
        static_offset,
        frame_budget,
    )
    model = flame_model_path(context)
    if model:
        command += ["--flame", bpy.path.abspath(model)]
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    log = out_dir.parent / f"{out_dir.name}.{LOG_NAME}"
    STATE.tracking_run = run = TrackingRun(BackendRun(command, log, env=env), out_dir, log)
    return run


def finish_tracking(context, run: TrackingRun, name: str | None = None) -> tuple[str, str]:
    """Close the run and import its tracking as a head named `name` (default: after the
    output folder). Returns (report type, message)."""
    STATE.tracking_run = None
    run.update()
    run.backend.close()
    tracking = run.out_dir / TRACKING_FILE
    if run.backend.cancelled_at is not None:
        if run.backend.returncode == 0 and tracking.is_file():  # done before the cancel came
            return "INFO", f"Tracking had finished before Cancel: its output is in {run.out_dir}"
        return "INFO", "Tracking cancelled; nothing was written"
    if run.backend.returncode != 0 or not tracking.is_file():
        reason = run.status.error or f"exit code {run.backend.returncode}"
        return "ERROR", f"tracking failed ({reason}); see {run.log}"
    head = import_tracking(context, tracking, name or run.out_dir.name)
    return "INFO", f"Tracked into {run.out_dir}; imported as {head.name}"


def import_tracking(context, tracking: Path, name: str):
    """The tracker's tracking.npz imported as a rigged head named `name`; returns the rig."""
    return import_sequence(context, tracking, {"name": name}, model_path=flame_model_path(context))
