"""ArchitectHead in torch (paper section 3): the model that trains, and the reference the numpy
runtime reproduces.

One frame: FLAME (+ teeth) with the avatar's identity -> UV position map at
S = round(S_max - l (S_max - S_min)) -> per texel [PE (75) | feature (64) | drive (K=20) | l]
-> five MLP heads -> Gaussians. The network works in *head space*: FLAME posed by expression,
neck, jaw and eyes but without the global rotation and translation, which are applied to the
decoded means and rotations at the end; so the decoder never sees the rigid head motion and its
offsets and rotations move with the head.

Choices (the paper leaves them to its supplement):
- Positional encoding: p = position - pe_centre in metres (pe_centre: the centre of the
  identity's bounding box), then [p, sin(2^k p), cos(2^k p)] for k = 0..pe_freqs - 1 (12 by
  default): the finest period, 2 pi / 2048 m = 3 mm, is about two texels of the 256 map on
  the face.
- Mapping network M: Linear(n_expr + 9, 128), ReLU, Linear(128, K), tanh. The tanh bounds the
  driving code, so extreme expression and pose codes cannot drive the decoder outside the range
  it was trained on (with the bounded PE and l, every decoder input is then bounded).
- Decoder: five heads, each an MLP 160 -> w -> w -> out with ReLU; w = 64 for the colour head
  (48 SH outputs carry most of the detail) and 32 for the offset, scale, rotation and opacity
  heads (3, 3, 4 and 1 outputs). The heads' first layers are one fused Linear(160, 4 x 32 + 64)
  (the same function as five layers, one matrix product). These widths keep the numpy decode of
  the ~60k Gaussians of LOD 0 on two CPU threads within the 150 ms budget (docs/bench_decode.md).
- Initialisation (so an untrained avatar is a sane surface): hidden layers keep torch's default
  init; output layers have weights x 0.1 and biases at the starting values below; feature maps
  start at N(0, 0.1^2).
    offset   Δμ = offset_unit (1 cm) x raw, bias 0: offsets of ~0.1 mm;
    scale    log s = base + raw, clamped to [log 0.1 mm, log 5 cm] before exp, where
             base = log(texel size on the face) = log(metres per UV unit of the face / S);
    rotation raw quaternion with bias (1, 0, 0, 0), normalised (a norm guard returns identity);
    opacity  logit bias = logit(init_opacity = 0.2);
    colour   SH DC bias (init_rgb - 0.5) / C0 (grey or the albedo's mean, linearised for a
             linear colour space), higher bands 0.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..flame.lbs import forward as flame_forward
from ..flame.lbs_torch import FlameLayer
from ..flame.model import FlameModel
from ..rotations import axis_angle_to_matrix, axis_angle_to_quaternion
from ..splat.colour_space import srgb_to_linear
from ..uv.layout import avatar_mesh
from ..uv.raster import UVRaster, face_texel_scale, position_map
from .config import QUAT_EPS, AvatarConfig
from .gaussians import SH_C0, Gaussians, quat_multiply
from .identity import bake_identity, offset_mesh
from .level_cache import LEVEL_BYTES, LevelCache
from .lod import resolution_for_lod
from .resample import resample_plan, texel_features

FEATURE_INIT_STD = 0.1
OUTPUT_INIT_GAIN = 0.1


class _Head(nn.Module):
    def __init__(self, width: int, n_hidden: int, out: int):
        super().__init__()
        self.hidden = nn.ModuleList(nn.Linear(width, width) for _ in range(n_hidden))
        self.out = nn.Linear(width, out)

    def forward(self, h):
        for layer in self.hidden:
            h = F.relu(layer(h))
        return self.out(h)


class Decoder(nn.Module):
    """Five MLP heads on the per-texel vector; their first layers fused into one."""

    def __init__(self, config: AvatarConfig):
        super().__init__()
        self.slices = config.head_slices()
        self.first = nn.Linear(config.in_dim, config.fused_width)
        self.heads = nn.ModuleDict(
            {
                name: _Head(config.head_width(name), config.head_layers - 1, width)
                for name, width in config.head_outputs().items()
            }
        )

    def forward(self, texel: list[torch.Tensor], frame: torch.Tensor) -> dict[str, torch.Tensor]:
        """Raw head outputs from the per-texel inputs, blocks of columns (N, PE), (N, feature),
        and the frame's, (drive | l), which every texel shares: they enter the first layer as
        part of its bias rather than as N copies of an input (the numpy runtime's form, too).
        Each block has its own product, so autograd skips the input gradient of a block that
        needs none (the PE: 75 of the 139 columns)."""
        w, k = self.first.weight, 0
        h = torch.addmv(self.first.bias, w[:, sum(x.shape[1] for x in texel) :], frame)
        for block in texel:
            h = F.linear(block, w[:, k : k + block.shape[1]], h)
            k += block.shape[1]
        # split, not slices: its backward is one concatenation rather than a zeroed copy of
        # h per head
        widths = [part.stop - part.start for part in self.slices.values()]
        h = dict(zip(self.slices, F.relu(h).split(widths, dim=1), strict=True))
        return {name: head(h[name]) for name, head in self.heads.items()}


class ArchHeadAvatar(nn.Module):
    def __init__(
        self,
        mesh: FlameModel,
        identity_shape,
        config: AvatarConfig,
        base_model_id: str,
        identity_offset=None,
    ):
        """`identity_offset`: (V_base,3) metres, the tracking's static offset (identity.py)."""
        super().__init__()
        if mesh.uv is None:
            raise ValueError("the avatar mesh needs a UV layout (see uv.layout.avatar_mesh)")
        self.config, self.mesh, self.base_model_id = config, mesh, base_model_id
        self.identity_offset = None if identity_offset is None else np.asarray(identity_offset)
        self.raster = UVRaster(mesh.uv, mesh.uv_faces)
        self.face_scale = face_texel_scale(mesh.v_template, mesh.faces, mesh.uv, mesh.uv_faces)
        self.register_buffer(
            "identity_shape", torch.as_tensor(np.asarray(identity_shape), dtype=torch.float32)
        )
        self._bake_identity()
        self.register_load_state_dict_post_hook(_bake_loaded_identity)
        self.register_buffer(
            "freqs", 2.0 ** torch.arange(config.pe_freqs, dtype=torch.float32), persistent=False
        )
        self.register_buffer(
            "pe_centre", torch.tensor(config.pe_centre, dtype=torch.float32), persistent=False
        )
        c = config.feature_dim
        self.features = nn.ParameterDict(
            {str(s): nn.Parameter(FEATURE_INIT_STD * torch.randn(c, s, s)) for s in config.levels}
        )
        self.mapping = nn.Sequential(
            nn.Linear(config.mapping_in, config.mapping_hidden),
            nn.ReLU(),
            nn.Linear(config.mapping_hidden, config.drive_dim),
        )
        self.decoder = Decoder(config)
        self._init_outputs()
        self.level_cache = LevelCache(self._build_level, LEVEL_BYTES)

    def _bake_identity(self) -> None:
        """FLAME with the identity in its template (identity.bake_identity), which saves the
        identity product of every frame; built again when a state dict brings another one."""
        shape = self.identity_shape.detach().cpu().numpy().copy()  # not a view of the buffer
        baked = getattr(self, "_baked_shape", None)
        if baked is not None and np.array_equal(baked, shape):
            return
        self.flame = FlameLayer(bake_identity(self.mesh, shape, self.identity_offset)).to(
            self.identity_shape.device
        )
        self._baked_shape = shape

    @classmethod
    def create(
        cls,
        model: FlameModel,
        identity_shape=None,
        config: AvatarConfig | None = None,
        uv_obj=None,
        cache=None,
        identity_offset=None,
    ) -> ArchHeadAvatar:
        """A fresh avatar for `model` (UV layout resolved, teeth added); config defaults to
        the paper's with the model's expression count, and is completed with the head centre
        and, when the model has an albedo, its mean colour."""
        mesh = avatar_mesh(model, uv_obj, cache)
        shape = np.zeros(model.n_shape) if identity_shape is None else np.asarray(identity_shape)
        rest = flame_forward(offset_mesh(mesh, identity_offset), shape=shape)[0]
        changes = {"pe_centre": tuple(float(x) for x in (rest.min(0) + rest.max(0)) / 2)}
        if mesh.albedo is not None:
            changes["init_rgb"] = tuple(float(x) for x in _mean_albedo(mesh))
        if config is None:
            config = AvatarConfig(n_expr=model.n_expr)
        config = replace(config, **changes)
        return cls(mesh, shape, config, model.model_id, identity_offset)

    def _init_outputs(self):
        starts = {
            "rotation": [1.0, 0.0, 0.0, 0.0],
            "opacity": [math.log(self.config.init_opacity / (1 - self.config.init_opacity))],
        }
        colour = torch.zeros(self.config.head_outputs()["colour"])
        rgb = np.asarray(self.config.init_rgb)
        if self.config.colour_space == "linear":
            rgb = srgb_to_linear(rgb)
        colour[:3] = (torch.tensor(rgb, dtype=torch.float32) - 0.5) / SH_C0
        with torch.no_grad():
            for name, head in self.decoder.heads.items():
                head.out.weight.mul_(OUTPUT_INIT_GAIN)
                head.out.bias.zero_()
                if name in starts:
                    head.out.bias.copy_(torch.tensor(starts[name]))
            self.decoder.heads["colour"].out.bias.copy_(colour)

    def level(self, size: int) -> dict[str, torch.Tensor]:
        """Per-resolution constants on the model's device: texels, face corners, barycentrics,
        base log scale (texel size on the face), the feature field's resample plan
        (`LevelCache`: every S a training run samples stays)."""
        return self.level_cache(size, self.identity_shape.device)

    def _build_level(self, size: int, device) -> dict[str, torch.Tensor]:
        table = self.raster.table(size)
        base = np.log(self.face_scale[table.face] / size)[:, None]
        return {
            "texel": torch.from_numpy(table.texel).to(device),
            "vert_idx": torch.from_numpy(self.mesh.faces[table.face]).to(device),
            "bary": torch.from_numpy(table.bary.astype(np.float32)).to(device),
            "base_log_scale": torch.from_numpy(base.astype(np.float32)).to(device),
            "resample": resample_plan(self.config.levels, size, self.config.tau, device),
        }

    def drive(self, expr=None, jaw=None, eyes=None) -> torch.Tensor:
        """The driving code (K,) from expression (padded to n_expr), jaw and eyes."""
        parts = [
            _code(expr, self.config.n_expr, "expr", self.identity_shape, pad=True),
            _code(jaw, 3, "jaw", self.identity_shape),
            _code(eyes, 6, "eyes", self.identity_shape),
        ]
        return torch.tanh(self.mapping(torch.cat(parts)))

    def pose(self, expr=None, jaw=None, neck=None, eyes=None):
        """FLAME posed by the codes, with the avatar's identity: vertices (V,3), joints (5,3)."""
        like = self.identity_shape
        expr_t = None if expr is None else _code(expr, self.mesh.n_expr, "expr", like, True)
        verts, joints, _ = self.flame.forward_full(
            expr=None if expr_t is None else expr_t[None],
            neck=_code(neck, 3, "neck", like)[None],
            jaw=_code(jaw, 3, "jaw", like)[None],
            eyes=_code(eyes, 6, "eyes", like)[None],
        )
        return verts[0], joints[0]

    def encode(self, positions: torch.Tensor) -> torch.Tensor:
        p = positions - self.pe_centre
        a = (p[:, None, :] * self.freqs[:, None]).reshape(len(p), -1)
        return torch.cat([p, torch.sin(a), torch.cos(a)], dim=1)

    def forward(
        self,
        lod: float = 0.0,
        *,
        expr=None,
        jaw=None,
        neck=None,
        eyes=None,
        rotation=None,
        translation=None,
        posed=None,
    ) -> Gaussians:
        """Gaussians of one frame. Codes are 1-D (or (1, n)); absent ones are zero. `posed`:
        `pose(expr, jaw, neck, eyes)` when the caller keeps it (training, per frame)."""
        cfg = self.config
        l, size = resolution_for_lod(lod, cfg.s_max, cfg.s_min)
        lv = self.level(size)
        like = self.identity_shape
        verts, joints = self.pose(expr, jaw, neck, eyes) if posed is None else posed
        pos = position_map(verts, lv["vert_idx"], lv["bary"])
        n = len(pos)
        parts = [self.encode(pos)]
        if cfg.levels:
            parts.append(texel_features(self.features, lv["resample"], lv["texel"]))
        frame = torch.cat([self.drive(expr, jaw, eyes), pos.new_full((1,), l)])
        raw = self.decoder(parts, frame)

        offsets = cfg.offset_unit * raw["offset"]
        rot = _code(rotation, 3, "rotation", like)
        j0 = joints[0]
        means = (pos + offsets - j0) @ axis_angle_to_matrix(rot).T + j0
        means = means + _code(translation, 3, "translation", like)
        q = raw["rotation"]
        norm = q.norm(dim=1, keepdim=True)
        identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=q.dtype, device=q.device)
        q = torch.where(norm > QUAT_EPS, q / norm.clamp_min(QUAT_EPS), identity)
        return Gaussians(
            means=means,
            log_scales=(lv["base_log_scale"] + raw["scale"]).clamp(
                cfg.log_scale_min, cfg.log_scale_max
            ),
            quats=quat_multiply(axis_angle_to_quaternion(rot)[None], q, stack=torch.stack),
            opacity_logits=raw["opacity"][:, 0],
            sh=raw["colour"].reshape(n, -1, 3),
            offsets=offsets,
            uv_texel=lv["texel"],
            resolution=size,
        )


def _bake_loaded_identity(avatar: ArchHeadAvatar, _incompatible) -> None:
    avatar._bake_identity()  # a module-level hook, so that the module still pickles


def _code(value, width: int, name: str, like: torch.Tensor, pad: bool = False) -> torch.Tensor:
    """A 1-D code tensor of `width` (zeros if absent; shorter expressions zero-padded)."""
    if value is None:
        return like.new_zeros(width)
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device).reshape(-1)
    if t.numel() > width or (t.numel() < width and not pad):
        raise ValueError(
            f"code '{name}': {t.numel()} values, the avatar takes "
            f"{'at most ' if pad else ''}{width}"
        )
    if not torch.isfinite(t).all():
        raise ValueError(f"code '{name}' contains NaN or Inf")
    return F.pad(t, (0, width - t.numel())) if pad else t


def _mean_albedo(mesh: FlameModel) -> np.ndarray:
    """Mean albedo colour (0..1) over the texels the layout covers."""
    h, w = mesh.albedo.shape[:2]
    size = 64
    texel = UVRaster(mesh.uv, mesh.uv_faces).table(size).texel
    rows = ((texel // size + 0.5) * h / size).astype(int)
    cols = ((texel % size + 0.5) * w / size).astype(int)
    return mesh.albedo[rows, cols].reshape(-1, 3).mean(0) / 255.0
