"""Per-frame refinement of the tracked codes, trained with the avatar (`lr.codes` > 0).

A monocular tracker fits landmarks, not pixels: a head turned a degree too far or an
expression slightly off in one frame makes that frame disagree with the others, and the one
set of weights that must draw them all blurs (GaussianAvatars refines its FLAME tracking
jointly with the avatar for the same reason). Each training frame gets a learned delta on
its global rotation and translation, neck, jaw, eyes and expression, zero at the start.

Each frame's deltas are parameters of their own, so Adam leaves the frames a step does not
render untouched (their gradient is None, not zero). Held-out frames keep their tracking: the
refinement fits what the avatar was shown, and `refined_sequence` writes it out for the
evaluation and for Blender, so that training frames are drawn as they were trained.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from torch import nn

REFINED = ("rotation", "translation", "neck", "jaw", "eyes", "expr")
# Adam moves a value by about its learning rate per step; lr.codes times these moves every
# code about as far in the image: 1e-3 rad turns a point 0.1 m from its joint by 0.1 mm, as
# 1e-4 m of translation moves it, and 1e-2 of an expression coefficient moves the face about
# as much.
STEP_SCALE = {
    "rotation": 1.0,
    "translation": 0.1,
    "neck": 1.0,
    "jaw": 1.0,
    "eyes": 1.0,
    "expr": 10.0,
}


class CodeRefinement(nn.Module):
    """The deltas of every training frame's codes (module docstring)."""

    def __init__(self, codes: list[dict]):
        super().__init__()
        self.frames = nn.ModuleList(
            nn.ParameterDict({k: nn.Parameter(torch.zeros_like(c[k])) for k in REFINED if k in c})
            for c in codes
        )

    def apply(self, i: int, codes: dict) -> dict:
        """Frame i's codes with its deltas added."""
        deltas = self.frames[i]
        return {k: v + deltas[k] if k in deltas else v for k, v in codes.items()}

    def param_groups(self, lr: float) -> list[dict]:
        """Adam groups, one per code, named "codes" (their rate is lr.codes x `scale`)."""
        return [
            {
                "params": [d[k] for d in self.frames if k in d],
                "name": "codes",
                "scale": STEP_SCALE[k],
                "lr": lr * STEP_SCALE[k],
            }
            for k in REFINED
            if any(k in d for d in self.frames)
        ]

    def state(self) -> dict[str, torch.Tensor]:
        """The deltas as (frames, width) CPU tensors by code, for the training state."""
        return {
            k: torch.stack([d[k].detach().cpu() for d in self.frames])
            for k in REFINED
            if all(k in d for d in self.frames)
        }

    def load(self, state: dict, where) -> None:
        """Deltas saved by `state`; ValueError when they do not fit these frames."""
        for k, saved in state.items():
            shape = (len(self.frames), *self.frames[0][k].shape) if k in self.frames[0] else None
            if shape is None or tuple(saved.shape) != shape:
                raise ValueError(
                    f"{where}: refinement.{k}: saved for shape {tuple(saved.shape)}, "
                    f"this run's frames need {shape} (resume with the same data and --frames)"
                )
            with torch.no_grad():
                for d, row in zip(self.frames, saved, strict=True):
                    d[k].copy_(row)

    def mean_size(self) -> dict[str, float]:
        """The mean absolute delta of each code over frames and values (a progress figure)."""
        return {k: float(v.abs().mean()) for k, v in self.state().items()}


def refined_sequence(sequence, indices: list[int], state: dict[str, torch.Tensor]):
    """`sequence` with the deltas of the training frames at `indices` (their positions in it)
    added; every other frame as tracked."""
    arrays = {}
    for k, deltas in state.items():
        values = np.array(getattr(sequence, k), dtype=np.float64)
        values[indices] += deltas.double().numpy()
        arrays[k] = values
    return replace(sequence, **arrays)
