"""The output folder of a training run and the names of its files, in one place: the trainer
writes them, the command line, the evaluation, the ablations and Blender's Train operator
read them (docs/formats.md, "Training run"). torch-free."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RunFolder:
    root: Path

    def __init__(self, root):
        object.__setattr__(self, "root", Path(root))

    @property
    def avatar(self) -> Path:
        """The avatar checkpoint (numpy-readable; avatar/checkpoint_format.py)."""
        return self.root / "avatar.npz"

    @property
    def state(self) -> Path:
        """What resumes the run: step, config, model and optimizer (torch, weights only)."""
        return self.root / "train_state.pt"

    @property
    def config(self) -> Path:
        """The training config the run used."""
        return self.root / "config.json"

    @property
    def log(self) -> Path:
        """The backend's output when another program started it (Blender, the ablations)."""
        return self.root / "train.log"

    @property
    def request(self) -> Path:
        """The config a caller asked for, passed to the backend with --config."""
        return self.root / "train_request.json"

    def clear_checkpoints(self) -> None:
        """Start over: without these a new run in the folder would refuse to start."""
        for path in (self.state, self.avatar):
            path.unlink(missing_ok=True)
