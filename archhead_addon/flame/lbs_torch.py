"""FLAME forward pass in torch (differentiable, batched); the twin of `lbs.py`."""

from __future__ import annotations

import torch

from ..rotations import axis_angle_to_matrix
from .lbs import batch_codes, model_arrays
from .model import N_JOINTS, FlameModel


class FlameLayer(torch.nn.Module):
    """The model's arrays as buffers; `forward(**codes)` returns posed vertices (B,V,3)."""

    def __init__(self, model: FlameModel, dtype=torch.float32):
        super().__init__()
        self.model = model
        np_dtype = torch.empty((), dtype=dtype).numpy().dtype
        for key, value in model_arrays(model, np_dtype).items():
            self.register_buffer(key, torch.from_numpy(value.copy()), persistent=False)
        self.register_buffer("parents", torch.from_numpy(model.parents), persistent=False)

    def forward(self, **codes) -> torch.Tensor:
        return self.forward_full(**codes)[0]

    def forward_full(self, **codes):
        """(vertices (B,V,3), joints (B,5,3), transforms (B,5,4,4)) as in lbs.forward_full."""
        dtype, device = self.v_template.dtype, self.v_template.device
        codes = {
            k: None if v is None else torch.as_tensor(v, dtype=dtype, device=device)
            for k, v in codes.items()
        }
        batch, c = batch_codes(self.model, codes)

        def code(key):
            v = c[key]
            if isinstance(v, int):
                return torch.zeros(batch, v, dtype=dtype, device=device)
            return v.expand(batch, v.shape[1])

        n_v = self.model.n_verts
        v_shaped = self.v_template.expand(batch, n_v, 3)
        if codes.get("static_offset") is not None:
            v_shaped = v_shaped + codes["static_offset"].reshape(n_v, 3)
        for key, start in (("shape", 0), ("expr", self.model.n_shape)):
            if c[key] is not None:
                k = c[key].shape[1]
                dirs = self.shapedirs[start : start + k]  # (k, 3V), as lbs.model_arrays lays it
                # a code given once (a clip's shape) is blended once, then broadcast
                v_shaped = v_shaped + (c[key] @ dirs).reshape(len(c[key]), n_v, 3)

        joints_rest = torch.einsum("jv,bvc->bjc", self.j_regressor, v_shaped)
        eyes = code("eyes")
        pose = torch.stack(
            [code("rotation"), code("neck"), code("jaw"), eyes[:, :3], eyes[:, 3:]], dim=1
        )
        rot = axis_angle_to_matrix(pose)
        eye = torch.eye(3, dtype=dtype, device=device)
        feature = (rot[:, 1:] - eye).reshape(batch, -1)
        v_posed = v_shaped + (feature @ self.posedirs.T).reshape(batch, n_v, 3)

        transforms = self._chain(rot, joints_rest)
        verts = self._skin(transforms, v_posed)
        trans = code("translation")[:, None, :]
        joints = torch.einsum("bjrc,bjc->bjr", transforms[:, :, :3, :3], joints_rest)
        joints = joints + transforms[:, :, :3, 3] + trans
        return verts + trans, joints, transforms

    def _skin(self, transforms: torch.Tensor, v_posed: torch.Tensor) -> torch.Tensor:
        """Linear blend skinning: each vertex's blended (3,4) transform, contiguous, applied
        to the vertex in homogeneous coordinates (2-3x faster than blending the rotation and
        the translation apart for a clip's frames at once, the tracker's fit, and no slower
        for one frame: benchmarks/tracking_changes.py)."""
        batch, n_v = v_posed.shape[:2]
        blend = torch.matmul(self.weights, transforms[:, :, :3, :].reshape(batch, -1, 12))
        homogeneous = torch.cat([v_posed, torch.ones_like(v_posed[..., :1])], dim=-1)
        return torch.einsum("bvrc,bvc->bvr", blend.view(batch, n_v, 3, 4), homogeneous)

    def _chain(self, rot: torch.Tensor, joints: torch.Tensor) -> torch.Tensor:
        parents = self.model.parents
        rel = torch.cat([joints[:, :1], joints[:, 1:] - joints[:, parents[1:]]], dim=1)
        top = torch.cat([rot, rel[..., None]], dim=-1)  # (B,5,3,4)
        bottom = torch.zeros_like(top[:, :, :1, :])
        bottom[..., 3] = 1
        local = torch.cat([top, bottom], dim=-2)
        world = [local[:, 0]]
        for j in range(1, N_JOINTS):
            world.append(world[parents[j]] @ local[:, j])
        world = torch.stack(world, dim=1)
        offset = torch.einsum("bjrc,bjc->bjr", world[:, :, :3, :3], joints)
        t = world[:, :, :3, 3] - offset
        top = torch.cat([world[:, :, :3, :3], t[..., None]], dim=-1)
        return torch.cat([top, world[:, :, 3:, :]], dim=-2)
