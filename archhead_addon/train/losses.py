"""The training loss of the paper (eq. 6-7):

    L     = L_rgb + λ_lpips L_lpips + λ_μ L_μ + λ_s (1 - 0.5 l) L_s [+ λ_a L_a + λ_r L_r]
    L_rgb = Huber(I, Î) + λ_parts Huber(I·B, Î·B)

I the ground-truth image, Î the render, B the eye/mouth parts mask, l the level of detail.
L_μ and L_s are the mean L2 norms of the Gaussians' offsets from the UV surface and of their
scales (metres, activated: exp of the log scales); denser levels (small l) get the larger
scale weight. L_lpips is ST-LPIPS (perceptual.py), the shift-tolerant LPIPS. L_a, not in
the paper, is the mean over Gaussians of max(0, ln(longest / shortest axis) - ln 10): zero
for every Gaussian within the axis ratio the evaluation counts as a needle
(evaluate.render.NEEDLE_RATIO), a pull on the log scales of the others only. L_r, not in
the paper either, is the mean of max(0, ln(longest / middle axis) - ln 3): it pulls on rods
(dashes) and leaves flat discs alone, which L_a pulls on too (docs/quality.md, "Rods").

Huber's threshold is not in the paper. On images in [0, 1] the common default of 1 makes it
plain half-MSE; 0.1 keeps it quadratic near convergence and linear (L1-like, robust) for the
gross errors of early training and misaligned pixels.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ..avatar.config import ROD_RATIO
from ..avatar.gaussians import Gaussians
from ..splat.autograd import ImageHuberCPU, cpu_float32
from .config import LossWeights


def huber(pred: torch.Tensor, target: torch.Tensor, delta: float) -> torch.Tensor:
    """Mean Huber loss: 0.5 x² where |x| <= delta, delta (|x| - 0.5 delta) beyond."""
    return F.huber_loss(pred, target, delta=delta)


def parts_huber(pred, target, parts, delta: float) -> torch.Tensor:
    """Huber(I·B, Î·B), the mean over every pixel (not only the masked ones, as in eq. 7).
    Images (H,W,3), parts (H,W) in [0, 1]."""
    b = parts[..., None]
    return huber(pred * b, target * b, delta)


def offset_norm(offsets: torch.Tensor) -> torch.Tensor:
    """L_μ: the mean L2 norm of the offsets (N,3)."""
    return offsets.norm(dim=1).mean()


def scale_norm(log_scales: torch.Tensor) -> torch.Tensor:
    """L_s: the mean L2 norm of the scales exp(log_scales) (N,3)."""
    return log_scales.exp().norm(dim=1).mean()


ANISOTROPY_RATIO = 10.0


def anisotropy_excess(log_scales: torch.Tensor) -> torch.Tensor:
    """L_a: the mean of max(0, ln(max axis / min axis) - ln ANISOTROPY_RATIO) over (N,3)."""
    spread = log_scales.max(dim=1).values - log_scales.min(dim=1).values
    return F.relu(spread - math.log(ANISOTROPY_RATIO)).mean()


def rod_excess(log_scales: torch.Tensor) -> torch.Tensor:
    """L_r: the mean of max(0, ln(longest axis / middle axis) - ln ROD_RATIO) over (N,3).
    A rod (one long axis, two short) draws a dash; a flat disc (two long axes), which
    `anisotropy_excess` pulls on too, is what a surface wants and costs nothing here."""
    longest = log_scales.max(dim=1).values
    middle = log_scales.sum(dim=1) - longest - log_scales.min(dim=1).values
    return F.relu(longest - middle - math.log(ROD_RATIO)).mean()


def scale_weight(weights: LossWeights, lod: float) -> float:
    """λ_s (1 - 0.5 l): twice the weight at the densest level as at the sparsest."""
    return weights.scale * (1.0 - 0.5 * lod)


class TrainingLoss:
    """Eq. 6 for one render; `perceptual` is an ST-LPIPS module (or None to leave it out)."""

    def __init__(self, weights: LossWeights, perceptual=None):
        self.weights, self.perceptual = weights, perceptual

    def __call__(self, *args, **kwargs) -> tuple[torch.Tensor, dict[str, float]]:
        """`terms`, with the terms as floats."""
        total, terms = self.terms(*args, **kwargs)
        return total, {k: float(v) for k, v in terms.items()}

    def terms(
        self,
        pred: torch.Tensor,
        target: torch.Tensor,
        parts: torch.Tensor,
        gaussians: Gaussians,
        lod: float,
        lpips_weight: float | None = None,
        reference=None,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """(total, terms): pred and target (H,W,3) in [0, 1], parts (H,W). The terms are the
        unweighted values of each part, and the total, detached 0-d tensors for logging (on
        the training device: reading them is a host sync, which a step does once).
        `lpips_weight` replaces λ_lpips for this call (0 leaves the perceptual term out);
        `reference`, the target's `perceptual_reference`, saves computing it again."""
        w = self.weights
        lpips_weight = w.lpips if lpips_weight is None else lpips_weight
        terms = dict(
            zip(("rgb", "parts"), self.image_terms(pred, target, parts), strict=True),
            offset=offset_norm(gaussians.offsets),
            scale=scale_norm(gaussians.log_scales),
        )
        total = (
            terms["rgb"]
            + w.parts * terms["parts"]
            + w.offset * terms["offset"]
            + scale_weight(w, lod) * terms["scale"]
        )
        if w.anisotropy > 0:
            terms["anisotropy"] = anisotropy_excess(gaussians.log_scales)
            total = total + w.anisotropy * terms["anisotropy"]
        if w.rod > 0:
            terms["rod"] = rod_excess(gaussians.log_scales)
            total = total + w.rod * terms["rod"]
        if self.perceptual is not None and lpips_weight > 0:
            if reference is None:
                reference = self.perceptual.reference(_nchw(target))
            terms["lpips"] = self.perceptual.compare(_nchw(pred), reference)[0]
            total = total + lpips_weight * terms["lpips"]
        terms["total"] = total
        return total, {k: v.detach() for k, v in terms.items()}

    def image_terms(self, pred, target, parts) -> tuple[torch.Tensor, torch.Tensor]:
        """(Huber(I, Î), Huber(I·B, Î·B)): float32 CPU images by the splat kernel in one
        pass (ImageHuberCPU), others by `huber` and `parts_huber`."""
        delta = self.weights.huber_delta
        if cpu_float32(pred, target, parts):
            return ImageHuberCPU.apply(pred, target, parts, delta)
        return huber(pred, target, delta), parts_huber(pred, target, parts, delta)

    def perceptual_reference(self, target: torch.Tensor):
        """The perceptual term's features of a target image (H,W,3), to share between the
        renders of one step."""
        return self.perceptual.reference(_nchw(target))


def _nchw(image: torch.Tensor) -> torch.Tensor:
    return image.permute(2, 0, 1)[None]
