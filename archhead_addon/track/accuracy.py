"""Tracking accuracy against known codes (the synthetic subject) and the benchmark command.

    python -m archhead_addon.track.accuracy --data SUBJECT [--frames N] [--known-focal]

tracks SUBJECT/frames as if they were a video and compares with SUBJECT/tracking.npz: mesh
vertex error in mm over the face region after a per-frame similarity alignment (median and
95th percentile), expression, jaw and head-rotation errors. It also fits the truth's own
landmark projections (perfect landmarks), which separates the fitter's limit from the
landmark detector's.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace

import numpy as np

from ..flame.lbs import forward
from ..flame.model import FlameModel, load_model
from ..rotations import axis_angle_to_matrix, matrix_to_axis_angle
from ..sequences import Sequence, read_sequence
from .embedding import face_region, landmark_embedding


def _similarity(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """src aligned onto dst by the least-squares similarity (Umeyama)."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, s, vt = np.linalg.svd(b.T @ a / len(a))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    r = u @ d @ vt
    scale = (s * np.diag(d)).sum() / a.var(0).sum()
    return scale * a @ r.T + md


def _vertices(model, seq: Sequence) -> np.ndarray:
    return forward(
        model,
        shape=seq.shape,
        expr=seq.expr,
        jaw=seq.jaw,
        neck=seq.neck,
        eyes=seq.eyes,
        rotation=seq.rotation,
        translation=seq.translation,
        static_offset=seq.static_offset,
    )


def vertex_errors(model: FlameModel, tracked: Sequence, truth: Sequence) -> np.ndarray:
    """Face-region vertex errors in mm (all frames x vertices), after similarity alignment."""
    region = face_region(model)
    pred = _vertices(model, tracked.fit_to_model(model))[:, region]
    true = _vertices(model, truth.fit_to_model(model))[:, region]
    return (
        np.concatenate(
            [np.linalg.norm(_similarity(p, t) - t, axis=1) for p, t in zip(pred, true, strict=True)]
        )
        * 1000
    )


def head_rotation(seq: Sequence) -> np.ndarray:
    """The head's orientation (global then neck) as one rotation matrix per frame."""
    return axis_angle_to_matrix(seq.rotation) @ axis_angle_to_matrix(seq.neck)


def code_errors(tracked: Sequence, truth: Sequence) -> dict:
    rel = head_rotation(tracked) @ np.swapaxes(head_rotation(truth), -1, -2)
    head = np.degrees(np.linalg.norm(matrix_to_axis_angle(rel), axis=-1))
    jaw = np.degrees(np.linalg.norm(tracked.jaw - truth.jaw, axis=-1))
    n = min(10, tracked.expr.shape[1], truth.expr.shape[1])
    expr = np.sqrt(((tracked.expr[:, :n] - truth.expr[:, :n]) ** 2).mean(axis=0))
    return {
        "head_rotation_deg_median": float(np.median(head)),
        "jaw_deg_median": float(np.median(jaw)),
        "expr_rms_first10": [round(float(e), 3) for e in expr],
    }


def summarise(errors: np.ndarray) -> dict:
    return {
        "median_mm": round(float(np.median(errors)), 3),
        "p95_mm": round(float(np.percentile(errors, 95)), 3),
    }


def main(argv=None) -> int:
    from .cli import add_refinement_flags
    from .fit import FitOptions, fit_landmarks, fitted_sequence
    from .photometric import PhotometricOptions
    from .pipeline import TrackOptions, track

    parser = argparse.ArgumentParser(
        prog="python -m archhead_addon.track.accuracy", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--data", required=True, help="a synthetic subject folder")
    parser.add_argument("--frames", type=int)
    parser.add_argument(
        "--known-focal", action="store_true", help="give the tracker the true focal length"
    )
    add_refinement_flags(parser)
    parser.add_argument(
        "--photometric-options",
        type=json.loads,
        default={},
        help="JSON of PhotometricOptions fields to change, e.g. '{\"weight\": 0.5}'",
    )
    args = parser.parse_args(argv)
    model = load_model(None)
    truth = read_sequence(f"{args.data}/tracking.npz")
    n = len(truth) if args.frames is None else min(args.frames, len(truth))
    truth = truth.subset(0, n)
    size = truth.image_size
    focal = float(truth.K[0, 0, 0]) if args.known_focal else None
    with tempfile.TemporaryDirectory() as tmp:
        report = track(
            f"{args.data}/frames",
            f"{tmp}/out",
            TrackOptions(
                size=max(size),
                max_frames=n,
                focal=focal,
                photometric=None
                if args.no_photometric
                else PhotometricOptions(**args.photometric_options),
                static_offset=args.static_offset,
            ),
        )
        tracked = read_sequence(f"{tmp}/out/tracking.npz")
    kept = np.isin(truth.frame_ids, tracked.frame_ids)
    truth_kept = replace(
        truth,
        **{
            k: getattr(truth, k)[kept]
            for k in (
                "shape",
                "expr",
                "jaw",
                "neck",
                "eyes",
                "rotation",
                "translation",
                "K",
                "w2c",
                "frame_ids",
            )
        },
    )
    # Perfect landmarks: the truth's own landmark points projected by its camera.
    emb = landmark_embedding(model)
    points = emb.points(_vertices(model, truth_kept), model.faces)
    cam = points @ truth.w2c[0, :3, :3].T + truth.w2c[0, :3, 3]
    perfect = (cam @ truth.K[0].T)[..., :2] / cam[..., 2:]
    fit = fit_landmarks(
        model,
        emb,
        perfect,
        truth_kept.frame_ids,
        truth.fps,
        size,
        FitOptions(focal=focal or float(truth.K[0, 0, 0])),
    )
    perfect_seq = fitted_sequence(fit.codes, truth_kept.frame_ids, truth.fps, "perfect")
    result = {
        "frames": int(kept.sum()),
        "known_focal": args.known_focal,
        "focal_px": report["focal_px_source"],
        "true_focal_px": float(truth.K[0, 0, 0]),
        "vertex_error": summarise(vertex_errors(model, tracked, truth_kept)),
        "codes": code_errors(tracked, truth_kept),
        "perfect_landmarks_vertex_error": summarise(vertex_errors(model, perfect_seq, truth_kept)),
        "landmark_residual_px": report["residual_px"],
        "jitter_px": report["jitter_px"],
        "photometric": report["photometric"],
        "photometric_options": None if args.no_photometric else args.photometric_options,
        "static_offset_mm": report["static_offset_mm"],
        "seconds_per_frame": report["seconds_per_frame"],
    }
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
