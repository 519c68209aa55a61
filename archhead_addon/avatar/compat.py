"""Does an avatar checkpoint fit an imported head? Problems are sentences a user can act on.

An imported head is built on a FLAME model with teeth (`flame.teeth.add_teeth`, whose model
id ends in "+teeth"); a checkpoint names the model before teeth and carries its UV layout.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .checkpoint_format import AvatarCheckpoint

TEETH_SUFFIX = "+teeth"
UV_TOLERANCE = 1e-5  # Blender stores UVs in float32


@dataclass
class HeadFacts:
    """What an imported head says about itself (read off Blender by the caller)."""

    model_id: str  # the head's archhead_model_id
    n_faces: int
    identity: np.ndarray
    n_expr: int
    loop_uvs: np.ndarray | None = None  # (3F,2) the mesh's UV map per face corner, if any


@dataclass
class Compatibility:
    errors: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def check_head(ckpt: AvatarCheckpoint, head: HeadFacts, flame_model_id: str) -> Compatibility:
    """Errors stop the avatar from loading; warnings say what will be adjusted."""
    out = Compatibility()
    head_base = head.model_id.removesuffix(TEETH_SUFFIX)
    if head_base != ckpt.model_id:
        out.errors.append(
            f"the avatar was trained on the model '{ckpt.model_id}', the head "
            f"was imported with '{head_base}'"
        )
    if flame_model_id != ckpt.model_id:
        out.errors.append(
            f"the avatar needs the FLAME model '{ckpt.model_id}', the "
            f"preferences give '{flame_model_id}' (set ArchHead's FLAME model)"
        )
    if head.n_faces != len(ckpt.uv_faces):
        out.errors.append(
            f"the head has {head.n_faces} faces, the avatar's UV layout {len(ckpt.uv_faces)}"
        )
    elif head.loop_uvs is not None:
        want = np.asarray(ckpt.uv, np.float64)[ckpt.uv_faces].reshape(-1, 2)
        if head.loop_uvs.shape != want.shape or np.abs(head.loop_uvs - want).max() > UV_TOLERANCE:
            out.errors.append(
                f"the head's UV map differs from the avatar's UV layout "
                f"({ckpt.uv_layout_id}): the avatar was trained with other UVs"
            )
    if out.errors:
        return out
    n = min(len(head.identity), len(ckpt.identity_shape))
    if len(head.identity) != len(ckpt.identity_shape) or not np.allclose(
        head.identity[:n], ckpt.identity_shape[:n], atol=1e-4
    ):
        out.warnings.append(
            "the head's identity shape differs from the avatar's; the avatar "
            "decodes on the identity chosen in its settings"
        )
    if head.n_expr > ckpt.config.n_expr:
        out.warnings.append(
            f"the head has {head.n_expr} expression shape keys, the avatar "
            f"reads {ckpt.config.n_expr}: the rest are ignored"
        )
    return out
