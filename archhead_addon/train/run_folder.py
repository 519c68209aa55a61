"""The output folder of a training run and the names of its files, in one place: the trainer
writes them, the command line, the evaluation, the ablations and Blender's Train operator
read them (docs/formats.md, "Training run"). torch-free and numpy-free.

A checkpoint writes train_state.pt, config.json and avatar.npz, each atomically, then
checkpoint.json: the step and a digest of each of the three. A kill between two of those
writes leaves files from two different steps, each whole; the manifest tells them apart
(`problems`), and `--resume` rewrites what lags from train_state.pt, which is written first.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..io.atomic import write_bytes_atomic
from ..io.digest import file_digest

MANIFEST_FORMAT, MANIFEST_VERSION = "archhead-checkpoint", 1


class RunFolder:
    def __init__(self, root):
        self.root = root = Path(root)
        self.avatar = root / "avatar.npz"  # the checkpoint (avatar/checkpoint_format.py)
        self.state = root / "train_state.pt"  # resumes the run (torch, weights only)
        self.config = root / "config.json"  # the training config the run used
        self.manifest = root / "checkpoint.json"  # the step and digests of the three above
        self.log = root / "train.log"  # the backend's output when another program ran it
        self.request = root / "train_request.json"  # a caller's config, given as --config
        # the tracking with the training frames' codes refined (lr.codes > 0; train/refine.py)
        self.tracking = root / "tracking_refined.npz"

    @property
    def checkpoint_files(self) -> tuple[Path, ...]:
        return (self.state, self.config, self.avatar)

    def clear_checkpoints(self) -> None:
        """Start over: without these a new run in the folder would refuse to start."""
        for path in (self.manifest, self.state, self.avatar):
            path.unlink(missing_ok=True)

    def write_manifest(self, step: int, total_steps: int) -> None:
        """The last write of a checkpoint: it vouches for the files written before it."""
        manifest = {
            "format": MANIFEST_FORMAT,
            "version": MANIFEST_VERSION,
            "step": int(step),
            "total_steps": int(total_steps),
            "files": {p.name: file_digest(p) for p in self.checkpoint_files},
        }
        write_bytes_atomic(self.manifest, json.dumps(manifest, indent=2).encode() + b"\n")

    def problems(self, step: int | None = None) -> list[str]:
        """Why the folder does not hold one whole checkpoint: missing files, files written
        after the manifest (a checkpoint cut short) and, given the state's `step`, files
        still of an earlier one. Empty when state, config, avatar and manifest agree."""
        missing = [p.name for p in (*self.checkpoint_files, self.manifest) if not p.is_file()]
        if missing:
            return [f"{name} is missing" for name in missing]
        try:
            manifest = json.loads(self.manifest.read_text())
            files, written = manifest["files"], int(manifest["step"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            return [f"{self.manifest.name} is unreadable ({exc})"]
        found, lagging = [], []
        for path in self.checkpoint_files:
            if files.get(path.name) != file_digest(path):
                found.append(f"{path.name} is newer than {self.manifest.name} (step {written})")
            elif path != self.config:  # a config may stay the same from step to step
                lagging.append(path)
        if step is not None and step != written:
            state = f"{self.state.name} of {step}"
            found += [f"{p.name} is of step {written}, {state}" for p in lagging]
        return found
