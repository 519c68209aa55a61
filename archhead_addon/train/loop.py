"""The two-stage training of the paper (sections 3.5 and 4.2) and two stages of the project's,
with checkpoints and resume.

Stage 1 (`stage1_steps`): every step renders one training frame at LOD 0 and trains the
feature field, the mapping network and the decoder. Stage 2 (`stage2_steps`): every step
renders the same frame at `lods_per_step` levels in [0, 1], accumulates their gradients (each
loss / n) and updates the feature field and the decoder; the mapping network is frozen.
The levels of a stage-2 step are stratified over [0, 1]: one drawn uniformly in each of n
equal bins. Rendering both ends in every step (as this project once did) made l = 0 and
l = 1 the best-trained levels and left their neighbours behind (l = 0.95 2.6 dB below l = 1);
stratified levels give a curve that falls with l and a higher mean over the 21 levels
(docs/training.md, "Two stages").
The learning rates decay exponentially within each stage, from their start to
`lr_final_ratio` of it: stage 2 starts at the full rates again, because its new task, the
sparse levels, needs them (at the decayed rates of one run-long schedule they barely moved).
Stages 3 and 4 (not the paper's) train the feature field alone, at the rate stage 2 ended
on, against the decoder stage 2 settled: stage 3 every level, at levels drawn as stage 2
draws them; stage 4 the sparsest level, at one level near LOD 1 a step (as `lod1_band`
draws it), the level LOD 1 draws almost all its features from (docs/quality.md, "Stages 3
and 4").

Randomness is a function of (seed, step) alone: the frame order (a permutation per epoch)
and the levels of stages 2 to 4. The step is therefore the whole random state, and a
resumed run takes the same steps as one that was never stopped.

Files in the output folder, each replaced atomically:
  avatar.npz       the avatar checkpoint (numpy-readable; avatar/checkpoint_format.py)
  train_state.pt   step, elapsed time, config, model and optimizer state, and a checksum of
                   them (io/checksum.py); torch.save of tensors and plain types only (what
                   torch.load(weights_only=True) reads), read back by state_file.py
  config.json      the training config of the run
  checkpoint.json  the step and the digests of the three above (run_folder.py)
A checkpoint writes them in that order: train_state.pt, config.json, avatar.npz, then the
manifest. Resume reads train_state.pt alone, so a kill between two writes loses nothing, and
`repair` rewrites the files that lag it (a kill during the last checkpoint once left a
finished run naming the previous checkpoint's avatar).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ..avatar.checkpoint import save_avatar
from ..avatar.config import AvatarConfig
from ..avatar.model import ArchHeadAvatar
from ..io.atomic import atomic_path, write_bytes_atomic
from ..io.checksum import KEY as CHECKSUM
from ..io.checksum import tree_checksum
from ..sequences.canonical import write_canonical
from ..splat import rasterization
from ..splat.colour_space import display_background, linear_to_srgb_torch
from ..splat.rendering import select_backend
from ..uv.layout import avatar_mesh
from .config import STAGE_STEPS, TrainConfig
from .losses import TrainingLoss
from .perceptual import ShiftTolerantLPIPS
from .progress import StepReport
from .refine import CodeRefinement, refined_sequence
from .run_folder import RunFolder
from .state_file import STATE_FORMAT, STATE_VERSION, read_train_state
from .time_limit import TimeLimit, predicted_rates

EMA = 0.9  # smoothing of the seconds-per-step estimate
POSE_CODES = ("expr", "jaw", "neck", "eyes")  # ArchHeadAvatar.pose's, in order


@dataclass
class Frame:
    """One training frame as tensors on the training device."""

    image: torch.Tensor  # (H,W,3) in [0, 1], composited over the background
    parts: torch.Tensor  # (H,W) eye / mouth mask B
    codes: dict  # expr, jaw, neck, eyes, rotation, translation (1-D tensors)
    K: np.ndarray  # (3,3) at the training resolution
    w2c: np.ndarray  # (4,4)
    index: int = -1  # the frame's position in the tracked sequence
    region: torch.Tensor | None = None  # (H,W,1) where the truth may hold the person (`cut`)


def frames_on_device(dataset, device: torch.device) -> list[Frame]:
    """The frames of a `train.dataset.FrameDataset` as tensors (codes without the identity,
    which the avatar holds)."""
    frames = []
    for i in range(len(dataset)):
        item = dataset[i]
        codes = {
            k: torch.as_tensor(v, device=device) for k, v in item["codes"].items() if k != "shape"
        }
        frames.append(
            Frame(
                torch.as_tensor(item["image"], device=device),
                torch.as_tensor(item["parts"], device=device),
                codes,
                item["K"].astype(np.float64),
                item["w2c"].astype(np.float64),
                int(item["index"]),
                torch.as_tensor(item["region"], device=device)[..., None],
            )
        )
    return frames


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' asked for, but torch sees no CUDA device")
    return torch.device(name)


def stage2_lods(n: int, u, end: float | None = None) -> list[float]:
    """The levels of a stage-2 step (module docstring) from n uniform numbers u in [0, 1);
    `end` replaces the last one (`lod1_share`)."""
    lods = [float((k + u[k]) / n) for k in range(n)]
    return lods if end is None else lods[:-1] + [end]


def stage2_cost_ratio(s_max: int, s_min: int, n: int, perceptual: bool) -> float:
    """A stage-2 step of n levels, as a multiple of a stage-1 step, until stage 2 times its
    own. Part of a CPU render's time does not grow with the Gaussians (the resample, the
    loss, ST-LPIPS when on): about half with the perceptual term (2.38 for three levels at
    128 / 32, measured 2.06), 0.2 without; the rest scales with the count, whose mean over a
    random level is (1 + r + r^2) / 3 of LOD 0's, r = s_min / s_max. The `cpu` preset (one
    level, no perceptual term): 0.55, measured 0.51 on the Pexels clip since the kernel took
    over the resample and the image terms (2026-11-29; before, 0.3 for the fixed part, 0.55
    and 0.61 measured)."""
    r = s_min / s_max
    fixed = 0.5 if perceptual else 0.2
    return n * (fixed + (1 - fixed) * (1 + r + r * r) / 3)


class Trainer:
    def __init__(
        self,
        config: TrainConfig,
        frames: list[Frame],
        avatar: ArchHeadAvatar,
        out_dir,
        background,
        device: torch.device,
        sequence=None,
    ):
        """`sequence`: the tracked sequence the frames come from; with `lr.codes` > 0 each
        checkpoint writes it refined beside the avatar (RunFolder.tracking)."""
        if not frames:
            raise ValueError("no training frames")
        self.config, self.frames, self.avatar = config, frames, avatar
        self.out_dir, self.device = Path(out_dir), device
        # the background as the renderer blends it (linearised for a linear colour space)
        self.background = torch.as_tensor(
            display_background(background, avatar.config.colour_space), dtype=torch.float32
        )
        self.image_background = torch.as_tensor(background, dtype=torch.float32, device=device)
        perceptual = ShiftTolerantLPIPS().to(device) if config.loss.lpips > 0 else None
        self.loss = TrainingLoss(config.loss, perceptual)
        groups = {
            "features": list(avatar.features.parameters()),
            "mapping": list(avatar.mapping.parameters()),
            "decoder": list(avatar.decoder.parameters()),
        }
        param_groups = [
            {"params": p, "name": k, "lr": getattr(config.lr, k)} for k, p in groups.items()
        ]
        self.refinement, self.sequence = None, sequence
        if config.lr.codes > 0:
            self.refinement = CodeRefinement([f.codes for f in frames]).to(device)
            param_groups += self.refinement.param_groups(config.lr.codes)
        # fused: one kernel per parameter rather than a dozen operations
        self.optimizer = torch.optim.Adam(param_groups, fused=True)
        self._posed_frames: dict[int, tuple] = {}
        self.step = 0  # steps done
        self.elapsed = 0.0  # training seconds over every session of the run
        self.backend = select_backend("auto", device)
        self._rate = dict.fromkeys((1, 2, 3, 4))  # smoothed seconds per step, by stage
        self.time_limit: TimeLimit | None = None  # `limit_time`
        # stage 4's level: the one LOD 1 blends most from (the levels are distinct sizes)
        self.sparsest = str(min(avatar.config.levels)) if avatar.config.levels else None

    @classmethod
    def create(
        cls,
        config: TrainConfig,
        frames,
        model,
        identity_shape,
        out_dir,
        background,
        device,
        identity_offset=None,
        sequence=None,
    ) -> Trainer:
        torch.manual_seed(config.seed)
        avatar = ArchHeadAvatar.create(
            model,
            identity_shape,
            config.avatar_config(model.n_expr),
            identity_offset=identity_offset,
        )
        return cls(config, frames, avatar.to(device), out_dir, background, device, sequence)

    @classmethod
    def resume(
        cls, state: dict, out_dir, frames, model, background, device, config=None, sequence=None
    ) -> Trainer:
        """The run as its last checkpoint (`load_state`) left it, with `config` (default: the
        state's). ValueError when `model` is not the FLAME model the run was started with."""
        trained_on = state.get("model_id")
        if trained_on is not None and trained_on != model.model_id:
            raise ValueError(
                f"{RunFolder(out_dir).state}: model_id: the run was started on "
                f"the FLAME model '{trained_on}', resumed with '{model.model_id}' "
                "(pass the same --flame as the run's first session)"
            )
        avatar = ArchHeadAvatar(
            avatar_mesh(model),
            state["model"]["identity_shape"].numpy(),
            AvatarConfig.from_json(state["avatar_config"]),
            model.model_id,
            _offset(state.get("identity_offset")),
        )
        try:
            avatar.load_state_dict(state["model"], strict=True)
        except RuntimeError as exc:  # a state of another model size (no model_id: version 1)
            raise ValueError(
                f"{RunFolder(out_dir).state}: model: the saved weights do not "
                f"fit the FLAME model '{model.model_id}' ({exc})"
            ) from exc
        config = config or state_config(state)
        trainer = cls(config, frames, avatar.to(device), out_dir, background, device, sequence)
        if trainer.refinement is not None and state.get("refinement"):
            trainer.refinement.load(state["refinement"], RunFolder(out_dir).state)
        trainer.optimizer.load_state_dict(state["optimizer"])
        for group in trainer.optimizer.param_groups:  # a state saved before Adam was fused
            group["fused"] = True  # brings its own setting with it
        trainer.step, trainer.elapsed = int(state["step"]), float(state["elapsed"])
        return trainer

    # -- schedule -------------------------------------------------------------------------

    def frame_index(self, step: int) -> int:
        n = len(self.frames)
        epoch, k = divmod(step, n)
        return int(np.random.default_rng([self.config.seed, epoch]).permutation(n)[k])

    def lods(self, step: int) -> list[float]:
        stage = self.config.stage(step)
        if stage == 1:
            return [0.0]
        cfg = self.config
        rng = np.random.default_rng([cfg.seed, 1 << 20, step])
        if stage == 4:
            return [self._near_lod1(rng)]
        u = rng.random(cfg.lods_per_step)
        end = None
        if cfg.lod1_share and rng.random() < cfg.lod1_share:
            end = self._near_lod1(rng)
        return stage2_lods(cfg.lods_per_step, u, end)

    def _near_lod1(self, rng) -> float:
        band = self.config.lod1_band
        return float(1 - band * rng.random() ** 2) if band else 1.0

    def lpips_weights(self, step: int, renders: int) -> list[float]:
        """λ_lpips for each render of a step: on every `lpips_every`-th step, weighted by that
        count; with `lpips_levels` "one", on one render of it, in turn, weighted by their
        count too (the step's loss is their mean), so that the term stays unbiased."""
        cfg = self.config
        if step % cfg.lpips_every:
            return [0.0] * renders
        weight = cfg.loss.lpips * cfg.lpips_every
        if cfg.lpips_levels == "all":
            return [weight] * renders
        turn = (step // cfg.lpips_every) % renders
        return [weight * renders if k == turn else 0.0 for k in range(renders)]

    def learning_rate_factor(self, step: int) -> float:
        """1 at the start of stages 1 and 2, decaying exponentially to lr_final_ratio at
        their end; stages 3 and 4 keep the rate stage 2 ended on."""
        cfg = self.config
        stage = cfg.stage(step)
        if stage > 2:
            return cfg.lr_final_ratio
        start, length = (
            (0, cfg.stage1_steps) if stage == 1 else (cfg.stage1_steps, cfg.stage2_steps)
        )
        return cfg.lr_final_ratio ** ((step - start) / length)

    # -- one step -------------------------------------------------------------------------

    def render(self, frame: Frame, lod: float, codes: dict | None = None):
        """(rgb (H,W,3), Gaussians) of a frame at level `lod` (with `codes` instead of the
        frame's own when given), cut to the frame's region with `cut` "region"."""
        if codes is None:
            g = self.avatar(lod, **frame.codes, posed=self._posed(frame))
        else:
            g = self.avatar(lod, **codes)
        h, w = frame.image.shape[:2]
        linear = self.avatar.config.colour_space == "linear"
        out = rasterization(
            g.means,
            g.quats,
            g.log_scales,
            g.opacity_logits,
            g.sh,
            frame.w2c,
            frame.K,
            w,
            h,
            background=self.background,
            num_threads=self.config.threads,
        )
        rgb = linear_to_srgb_torch(out.rgb) if linear else out.rgb
        if self.config.cut == "region" and frame.region is not None:
            rgb = torch.lerp(self.image_background, rgb, frame.region)
        return rgb, g

    def _posed(self, frame: Frame):
        """FLAME posed by the frame's own codes, once per frame: they and the identity stay
        fixed through a run (a refined frame's codes go through FLAME every step)."""
        kept = self._posed_frames.get(id(frame))
        if kept is None or kept[0] is not frame:
            with torch.no_grad():
                posed = self.avatar.pose(*(frame.codes.get(k) for k in POSE_CODES))
                kept = self._posed_frames[id(frame)] = (frame, posed)
        return kept[1]

    def train_step(self) -> StepReport:
        step, cfg = self.step, self.config
        stage = cfg.stage(step)
        self._train_parts(stage)
        for group in self.optimizer.param_groups:
            rate = getattr(cfg.lr, group["name"]) * group.get("scale", 1.0)
            group["lr"] = rate * self.learning_rate_factor(step)
        index = self.frame_index(step)
        frame = self.frames[index]
        codes = None if self.refinement is None else self.refinement.apply(index, frame.codes)
        lods = self.lods(step)
        start = time.perf_counter()
        self.optimizer.zero_grad(set_to_none=True)
        sums: dict[str, torch.Tensor] = {}
        lpips_weights = self.lpips_weights(step, len(lods))
        reference = None
        if self.loss.perceptual is not None and any(lpips_weights):
            reference = self.loss.perceptual_reference(frame.image)
        for lod, lpips_weight in zip(lods, lpips_weights, strict=True):
            rgb, g = self.render(frame, lod, codes)
            total, terms = self.loss.terms(
                rgb, frame.image, frame.parts, g, lod, lpips_weight, reference
            )
            (total / len(lods)).backward()
            for k, v in terms.items():
                sums[k] = sums.get(k, 0.0) + v / len(lods)
        self.optimizer.step()
        # the step's one read of device values (each term's own would sync a GPU each time)
        sums = dict(zip(sums, torch.stack(list(sums.values())).tolist(), strict=True))
        seconds = time.perf_counter() - start
        self.step += 1
        self.elapsed += seconds
        rate = self._rate[stage]
        self._rate[stage] = seconds if rate is None else EMA * rate + (1 - EMA) * seconds
        return StepReport(
            stage,
            self.step,
            cfg.total_steps,
            sums,
            lods,
            self._rate[stage],
            self.eta(),
            self.elapsed,
        )

    def _train_parts(self, stage: int) -> None:
        """What a stage trains: everything in stage 1; the mapping network is frozen from
        stage 2, the decoder and the codes' refinement from stage 3; stage 4 trains the
        sparsest feature level alone. A frozen part has no gradient, which Adam skips."""
        self.avatar.mapping.requires_grad_(stage == 1)
        self.avatar.decoder.requires_grad_(stage < 3)
        for size, level in self.avatar.features.items():
            level.requires_grad_(stage < 4 or size == self.sparsest)
        if self.refinement is not None:
            self.refinement.requires_grad_(stage < 3)

    def eta(self) -> float:
        cfg, rates = self.config, self._predicted(self._rate)
        seconds, start = 0.0, 0
        for stage, steps in enumerate(cfg.stage_steps, start=1):
            left = max(start + steps - max(start, self.step), 0)
            start += steps
            seconds += left * (rates[stage] or 0.0)
        return seconds

    def _predicted(self, rates: dict) -> dict:
        """`rates` (seconds a step by stage, None where not measured) with the missing ones
        predicted (time_limit.predicted_rates)."""
        a, cfg = self.avatar.config, self.config
        ratio = stage2_cost_ratio(a.s_max, a.s_min, cfg.lods_per_step, cfg.loss.lpips > 0)
        return predicted_rates(rates, ratio)

    # -- time limit -----------------------------------------------------------------------

    def limit_time(self, start: float, minutes: float) -> None:
        """End the run by `minutes` after `start` (time.monotonic()), its steps fitted as it
        goes (time_limit.py); `minutes` 0: the config's steps, however long they take."""
        self.time_limit = None
        if minutes > 0:
            self.time_limit = TimeLimit.minutes_from(start, minutes, self.config.stage_steps)

    def _fit_to_time(self, stage: int, seconds: float) -> str | None:
        """After a step of `stage` that took `seconds`, refit the steps when due
        (TimeLimit.observe); what the stage's first fit gives, said."""
        limit, cfg = self.time_limit, self.config
        if not limit.observe(stage, seconds):
            return None
        steps = limit.fit(
            cfg.stage_steps, self.step, self._predicted(limit.rates()), cfg.checkpoint_every
        )
        if steps != cfg.stage_steps:  # (a new config checks every value: 0.16 ms)
            self.config = replace(cfg, **dict(zip(STAGE_STEPS, steps, strict=True)))
        if stage in limit.announced:
            return None
        limit.announced.add(stage)
        share = sum(steps) / max(sum(limit.planned), 1)
        return (
            f"time limit: {max(limit.deadline - time.monotonic(), 0) / 60:.1f} min left; "
            f"stages of {' / '.join(f'{n:,}' for n in steps)} steps "
            f"({share:.2f} of the config's)"
        )

    # -- files ----------------------------------------------------------------------------

    def save(self) -> Path:
        """Write a checkpoint in the module docstring's order; returns the avatar's path."""
        state = {
            "format": STATE_FORMAT,
            "version": STATE_VERSION,
            "step": self.step,
            "elapsed": self.elapsed,
            "config": self.config.to_json(),
            "model_id": self.avatar.base_model_id,
            "avatar_config": self.avatar.config.to_json(),
            "model": {k: v.detach().cpu() for k, v in self.avatar.state_dict().items()},
            "identity_offset": _tensor(self.avatar.identity_offset),
            "optimizer": _to_cpu(self.optimizer.state_dict()),
        }
        if self.refinement is not None:
            state["refinement"] = self.refinement.state()
        state[CHECKSUM] = tree_checksum(_numpy_tree(state))
        folder = RunFolder(self.out_dir)
        with atomic_path(folder.state) as tmp:
            torch.save(state, tmp)
        self.write_config()
        if self.refinement is not None and self.sequence is not None:
            indices = [f.index for f in self.frames]
            refined = refined_sequence(self.sequence, indices, state["refinement"])
            write_canonical(refined, folder.tracking)
        save_avatar(folder.avatar, self.avatar)
        folder.write_manifest(self.step, self.config.total_steps)
        return folder.avatar

    def write_config(self) -> None:
        """config.json, unless it already says the same."""
        path, text = RunFolder(self.out_dir).config, self.config.to_json().encode() + b"\n"
        if not (path.is_file() and path.read_bytes() == text):
            write_bytes_atomic(path, text)

    def repair(self) -> list[str]:
        """Rewrite the checkpoint from this (resumed) state where the folder's files do not
        agree with it; returns what was wrong (nothing: nothing written)."""
        found = RunFolder(self.out_dir).problems(self.step)
        if found:
            self.save()
        return found

    def run(
        self,
        on_step: Callable[[StepReport], None],
        on_checkpoint: Callable[[int, Path], None],
        should_stop: Callable[[], bool] = lambda: False,
        on_message: Callable[[str], None] = lambda text: None,
    ) -> bool:
        """Train to the end (True) or until should_stop() after a step (False, saved);
        `on_message` hears what a time limit's fits give."""
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if self.step == 0:
            self.write_config()  # a resumed run's is in its checkpoint (`repair`)
        every = self.config.checkpoint_every
        while self.step < self.config.total_steps:
            started = time.monotonic()
            report = self.train_step()
            if not all(math.isfinite(v) for v in report.loss.values()):
                raise FloatingPointError(f"non-finite loss at step {self.step}: {report.loss}")
            if self.time_limit is not None:  # the report says the steps as fitted
                said = self._fit_to_time(report.stage, time.monotonic() - started)
                total, eta = self.config.total_steps, self.eta()
                report = replace(report, total=total, eta_seconds=eta)
                if said:
                    on_message(said)
            on_step(report)
            last, stop = self.step == self.config.total_steps, should_stop()
            if last or stop or self.step % every == 0:
                saving = time.monotonic()
                on_checkpoint(self.step, self.save())
                if self.time_limit is not None:
                    self.time_limit.save_seconds = time.monotonic() - saving
            if stop and not last:
                return False
        return True


def load_state(path) -> dict:
    """A training state file (tensors on the CPU), read without torch.load and checked key
    by key (state_file.py); InputError names the key."""
    state = _as_tensors(read_train_state(path))
    return state


def state_config(state: dict, where=None) -> TrainConfig:
    """The config a state was saved with; `where` (its file) names it in errors and in the
    warning when its thread count is more than this machine's cores."""
    return TrainConfig.read(json.loads(state["config"]), where)


def _map_leaves(fn, value):
    """fn of every leaf of a state tree, through dicts, lists and tuples."""
    if isinstance(value, dict):
        return {k: _map_leaves(fn, v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_map_leaves(fn, v) for v in value)
    return fn(value)


def _as_tensors(value):
    """The checked state's numpy arrays as CPU tensors."""
    return _map_leaves(lambda a: torch.from_numpy(a) if isinstance(a, np.ndarray) else a, value)


def _numpy_tree(value):
    """The state as state_file.py reads it back (CPU tensors as numpy views, bfloat16 as
    float32), for its checksum."""

    def leaf(t):
        if not isinstance(t, torch.Tensor):
            return t
        return (t.float() if t.dtype == torch.bfloat16 else t).numpy()

    return _map_leaves(leaf, value)


def _tensor(array):
    """A numpy array as a tensor for torch.save (None stays None)."""
    return None if array is None else torch.from_numpy(np.asarray(array, np.float64))


def _offset(tensor):
    """The saved identity offset back as numpy (None stays None)."""
    return None if tensor is None else tensor.numpy()


def _to_cpu(value):
    """A copy of an optimizer state dict with every tensor on the CPU."""
    return _map_leaves(lambda t: t.detach().cpu() if isinstance(t, torch.Tensor) else t, value)
