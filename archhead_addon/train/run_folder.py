"""The output folder of a training run and the names of its files, in one place: the trainer
writes them, the command line, the evaluation, the ablations and Blender's Train operator
read them (docs/formats.md, "Training run"). torch-free."""

from __future__ import annotations

from pathlib import Path


class RunFolder:
    def __init__(self, root):
        self.root = root = Path(root)
        self.avatar = root / "avatar.npz"  # the checkpoint (avatar/checkpoint_format.py)
        self.state = root / "train_state.pt"  # resumes the run (torch, weights only)
        self.config = root / "config.json"  # the training config the run used
        self.log = root / "train.log"  # the backend's output when another program ran it
        self.request = root / "train_request.json"  # a caller's config, given as --config

    def clear_checkpoints(self) -> None:
        """Start over: without these a new run in the folder would refuse to start."""
        for path in (self.state, self.avatar):
            path.unlink(missing_ok=True)
