"""Avatar from Video: a video to an avatar on its head, in one operator.

The stages are the ones Track Video, File > Import and Train Avatar run, chained in one
output folder laid out as `python -m archhead_addon avatar VIDEO --out DIR` lays it out
(archhead_addon/video_avatar.py), so either one carries on from what the other left:

  1. track the video into OUT/data (Track Video's backend: tracking.start_tracking);
  2. import OUT/data/tracking.npz as a rigged head (or find the head already imported from
     it in this file);
  3. train OUT/data into OUT/run with the chosen preset and the interleaved holdout (Train
     Avatar's backend: training.start_training), resumed when OUT/run holds a stopped run;
     with a time limit, within what tracking left of it (as the command line's `--minutes`);
  4. load OUT/run/avatar.npz onto the head (Load Avatar's avatar_objects.load_avatar).

A finished stage is skipped (the tracker writes OUT/data whole or not at all; a finished
run's manifest says so), so running Avatar from Video again on the same folder after Cancel,
a quit or a crash goes on from the stage it reached. The heavy work stays in the backend
processes; this module only starts, watches and chains them. Each stage's run is also the
tracking or training run of STATE, so quitting Blender or loading another file stops it as it
stops Track Video's and Train Avatar's (training saves a checkpoint first).
"""

from __future__ import annotations

import time
from pathlib import Path

import bpy

from archhead_addon.io.errors import InputError
from archhead_addon.threads import openmp_waiting_env
from archhead_addon.track import FRAME_BUDGET
from archhead_addon.train.dataset import FRAMES_DIR, TRACKING_FILE
from archhead_addon.train.run_folder import RunFolder
from archhead_addon.video_avatar import DATA, RUN, minutes_for_training, stages_done

from .avatar_objects import head_of, load_avatar
from .state import STATE
from .tracking import current_tracking, finish_tracking, import_tracking, start_tracking
from .training import current_run, finish_training, start_training, training_settings

HOLDOUT = "interleaved"  # as the command line's `avatar` trains
TRACK_SHARE = 0.3  # of the progress bar; training has the rest (import and load take seconds)


class VideoAvatarRun:
    """The stages of one Avatar from Video: which one is going, its backend run, the head."""

    def __init__(
        self,
        video,
        out_dir,
        preset: str,
        frames: int,
        size: int,
        photometric: bool,
        frame_budget: int = FRAME_BUDGET,
        minutes: float = 0.0,
    ):
        self.video, self.out = video, Path(out_dir).resolve()
        self.minutes, self.started = minutes, time.monotonic()  # the time limit (0: none)
        self.preset, self.frames, self.size, self.photometric = preset, frames, size, photometric
        self.frame_budget = frame_budget  # 0: every frame
        self.name = self.out.name  # the head's name
        self.stage = "start"  # track, train, done
        self.tracking = None
        self.training = None
        self.head_name: str | None = None  # the head (mesh) once imported or found
        self.cancelled = False
        self.result: tuple[str, str] | None = None  # (report type, message) once over
        # how the stages' OpenMP threads wait, chosen before the tracker loads the cores:
        # training, choosing when it starts, would take the tracker's load for other jobs'
        self.waiting: dict[str, str] = {}

    @property
    def data(self) -> Path:
        return self.out / DATA

    @property
    def run_dir(self) -> Path:
        return self.out / RUN

    # -- stages ---------------------------------------------------------------------------------
    def start(self, context) -> None:
        done = stages_done(self.out)
        self.waiting = openmp_waiting_env()
        if not done["tracked"]:
            if not str(self.video).strip():
                raise ValueError("Video: choose the video to track")
            self.stage = "track"
            self.tracking = start_tracking(
                context,
                self.video,
                self.data,
                self.frames,
                self.size,
                self.photometric,
                env=self.waiting,
                frame_budget=self.frame_budget,
            )
            return
        self._train(context, done["trained"])

    def _train(self, context, trained: bool) -> None:
        """Import (or find) the head, then train, or load a finished run's avatar."""
        head = find_head(self.data / TRACKING_FILE)
        if head is None:
            head = head_of(import_tracking(context, self.data / TRACKING_FILE, self.name))
        self.head_name = head.name
        if trained:
            self._load(context, head)
            return
        settings = training_settings({"holdout": HOLDOUT}, self.preset)
        resume = RunFolder(self.run_dir).state.is_file()
        minutes = minutes_for_training(self.minutes, self.started)  # ValueError: none left
        self.stage = "train"
        self.training = start_training(
            context,
            self.data / FRAMES_DIR,
            self.data / TRACKING_FILE,
            self.run_dir,
            settings,
            resume,
            head.name,
            env=self.waiting,
            minutes=minutes,
        )
        self.training.resume_hint = self.resume_hint()

    def _load(self, context, head) -> None:
        checkpoint = RunFolder(self.run_dir).avatar
        obj, _warnings = load_avatar(context, head, checkpoint)
        self.stage = "done"
        self.result = ("INFO", f"Avatar from Video: {obj.name} ({checkpoint}) on {head.name}")

    def update(self, context) -> bool:
        """Read the backend's progress; go on to the next stage when one ends. True once
        the whole run is over (finished, cancelled or failed: `result` says which)."""
        if self.result is not None:
            return True
        try:
            if self.stage == "track":
                if self.tracking.update():
                    self._tracked(context)
            elif self.stage == "train":
                if self.training.update():
                    self._trained(context)
        except (InputError, OSError, ValueError) as exc:
            self.result = ("ERROR", str(exc))
        return self.result is not None

    def _tracked(self, context) -> None:
        run, self.tracking = self.tracking, None
        kind, message = finish_tracking(context, run, self.name)  # imports the head
        if self.cancelled or kind != "INFO":
            stopped = f"Avatar from Video stopped while tracking ({message})"
            self.result = (
                "WARNING" if kind == "INFO" else kind,
                f"{stopped}. To go on: {self.resume_hint()}",
            )
            return
        self._train(context, stages_done(self.out)["trained"])

    def _trained(self, context) -> None:
        run, self.training = self.training, None
        if self.cancelled:
            run.head_name = None  # a stopped run is not loaded: Resume goes on with it
        kind, message = finish_training(context, run)  # loads the finished avatar
        if self.cancelled or kind != "INFO":
            self.result = (
                kind,
                f"Avatar from Video stopped while training ({message}). To go on: "
                + self.resume_hint(),
            )
            return
        self.stage = "done"
        self.result = ("INFO", f"Avatar from Video: {message}")

    def cancel(self) -> None:
        self.cancelled = True
        for run in (self.tracking, self.training):
            if run is not None:
                run.backend.cancel()

    def resume_hint(self) -> str:
        """How to go on (after "To go on: ")."""
        return f"Avatar from Video again with Output {self.out}"

    # -- what the panel and the status bar show ----------------------------------------------
    @property
    def fraction(self) -> float:
        if self.stage == "track" and self.tracking is not None:
            return TRACK_SHARE * self.tracking.fraction
        if self.stage == "train" and self.training is not None:
            return TRACK_SHARE + (1 - TRACK_SHARE) * self.training.fraction
        return 1.0 if self.stage == "done" else 0.0

    def step_text(self) -> str:
        """Which stage, in a line the default sidebar width holds."""
        if self.stage == "track":
            return "Step 1 of 2: tracking"
        if self.stage == "train":
            return f"Step 2 of 2: training ({self.preset})"
        return "Starting ..."

    def bar_text(self) -> str:
        if self.stage == "track" and self.tracking is not None:
            return self.tracking.summary()
        if self.stage == "train" and self.training is not None:
            return self.training.bar_text()
        return "Starting ..."

    def detail_text(self) -> str:
        if self.stage == "train" and self.training is not None:
            return self.training.rate_text()
        return ""

    def summary(self) -> str:
        """The status bar's line."""
        if self.stage == "track" and self.tracking is not None:
            return f"tracking (1 of 2): {self.tracking.summary()}"
        if self.stage == "train" and self.training is not None:
            return f"training (2 of 2): {self.training.summary()}"
        return "Starting ..."


def current_video_run() -> VideoAvatarRun | None:
    return STATE.video_run


def find_head(tracking: Path):
    """The head already imported from `tracking` in this file (a resumed run keeps it)."""
    tracking = tracking.resolve()
    for obj in bpy.data.objects:
        source = obj.get("archhead_sequence") if "archhead_model_id" in obj else None
        if source and Path(bpy.path.abspath(str(source))).resolve() == tracking:
            return obj
    return None


def folder_state(out_dir) -> str:
    """What Avatar from Video will do with the folder (the dialog says it): "" for a new
    one."""
    if not out_dir:
        return ""
    out = Path(bpy.path.abspath(out_dir))
    if not out.is_dir():
        return ""
    done = stages_done(out)
    if done["trained"]:
        return "Trained here: loads the avatar"
    if done["tracked"]:
        run = RunFolder(out / RUN)
        return "Tracked here: resumes training" if run.state.is_file() else "Tracked here: trains"
    return ""


def start_video_avatar(
    context,
    video,
    out_dir,
    preset: str,
    frames: int = 0,
    size: int = 512,
    photometric: bool = True,
    frame_budget: int = FRAME_BUDGET,
    minutes: float = 0.0,
) -> VideoAvatarRun:
    """Start (or go on with) Avatar from Video into `out_dir`; the first stage that is not
    done yet starts at once."""
    if current_video_run() is not None or current_run() is not None:
        raise ValueError("a run is already going; cancel it first")
    if current_tracking() is not None:
        raise ValueError("a tracking run is already going; cancel it first")
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    run = VideoAvatarRun(video, out, preset, frames, size, photometric, frame_budget, minutes)
    STATE.video_run = run
    try:
        run.start(context)
    except BaseException:
        STATE.video_run = None
        raise
    return run


def finish_video_avatar(context, run: VideoAvatarRun) -> tuple[str, str]:
    """Close the run. Returns (report type, message)."""
    STATE.video_run = None
    return run.result or ("ERROR", "Avatar from Video ended without a result")
