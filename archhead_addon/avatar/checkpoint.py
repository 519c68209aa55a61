"""Save and load the torch avatar as the numpy-readable checkpoint (checkpoint_format.py)."""

from __future__ import annotations

import torch

from .checkpoint_format import AvatarCheckpoint, checkpoint_mesh, read_checkpoint, write_checkpoint
from .model import ArchHeadAvatar


def save_avatar(path, avatar: ArchHeadAvatar) -> None:
    params = {
        k: v.detach().cpu().float().numpy()
        for k, v in avatar.state_dict().items()
        if k != "identity_shape"
    }
    write_checkpoint(
        path,
        AvatarCheckpoint(
            config=avatar.config,
            model_id=avatar.base_model_id,
            uv=avatar.mesh.uv,
            uv_faces=avatar.mesh.uv_faces,
            identity_shape=avatar.identity_shape.detach().cpu().numpy(),
            params=params,
            identity_offset=avatar.identity_offset,
        ),
    )


def load_avatar(path, flame=None, device="cpu") -> ArchHeadAvatar:
    """The avatar of a checkpoint; `flame` is the FLAME model it was trained on (a FlameModel,
    a file, or None for the built-in one)."""
    ckpt = read_checkpoint(path)
    mesh = checkpoint_mesh(ckpt, flame, path)
    avatar = ArchHeadAvatar(
        mesh, ckpt.identity_shape, ckpt.config, ckpt.model_id, ckpt.identity_offset
    )
    state = {k: torch.from_numpy(v) for k, v in ckpt.params.items()}
    state["identity_shape"] = torch.from_numpy(ckpt.identity_shape)
    avatar.load_state_dict(state, strict=True)
    return avatar.to(device)
