"""Where a training step's time goes: this tree's step against a plain rebuild of it.

    python benchmarks/training_profile.py [--data DIR] [--config cpu|FILE]
                                          [--avatar RUN/avatar.npz] [--steps 8] [--threads 2]

Runs real steps of `train.loop.Trainer` (stage 1, then stage 2 from step `stage1_steps`) on
a subject folder, each from the same avatar (the steps' updates are undone), alternating,
step by step, this tree's step ("after") with a plain one ("before": the straightforward
torch form of the parts that the step's optimisations replace, so the ratios say what each
optimisation is worth), whose parts this file rebuilds:
- the feature-field resample: F.interpolate per level, a channel-major blend, texels read
  by advanced indexing (`interpolated_texel_features`), not `avatar.resample`'s products;
- ST-LPIPS: channel-major, the first convolution and its blur unfolded with the input
  gradient by the library (`LibraryLPIPS`), and the target's features computed again for
  every render of a step;
- the decoder's first layer on the concatenated texel inputs, the heads' inputs sliced
  (`concatenated_decoder_forward`).
(Not rebuilt: the splat kernel, whose versions `splat_versions.py` compares, and FLAME's
identity product per frame, which the template bakes in, 1-2 % of a render.)

The split times each part alone, forward and backward, on the same frame and levels as the
step: the resample; the rest of the avatar (FLAME, position map, PE, the heads: the
"decoder"); the splat kernel; ST-LPIPS (on the steps that use it, once per render with its
own reference); Adam; and the data (the step's frame and levels; the frames are in memory
from the start). "other" is what the step took beyond them (the losses, zeroing, autograd's
own work, and in "after" minus the references a step shares) and goes negative when the
machine's load moved between the measurements. Ratios are of medians over the same steps.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import os
import statistics
import tempfile
import time
from functools import partial
from pathlib import Path

from archhead_addon.avatar.lod import resolution_for_lod
from archhead_addon.heap import keep_freed_memory
from archhead_addon.threads import WAITING, choose_openmp_waiting
from archhead_addon.timing import restart_with_threads

DEFAULT_DATA = Path("out/synth_track")  # scripts/synthetic_subject.py --frames 120 --size 256
PARTS = ("resample", "decoder", "kernel", "ST-LPIPS", "Adam", "data")
RATIOS = ("resample", "decoder", "ST-LPIPS")  # the parts "before" rebuilds


def interpolated_texel_features(features, plan, texel):
    """The resample without the matrix form, for the 'before' column: each level through
    F.interpolate (its own copy at S included), blended channel-major, texels indexed."""
    import torch.nn.functional as F

    key, _, a = plan[0]
    size = features[key].shape[1] if a is None else a.shape[0]
    out = 0
    for key, weight, _ in plan:
        resized = F.interpolate(
            features[key][None], size=(size, size), mode="bicubic", align_corners=False
        )[0]
        out = out + weight * resized
    return out.reshape(out.shape[0], -1)[:, texel].T


def concatenated_decoder_forward(decoder, texel, frame):
    """`Decoder.forward` in its plain form: one product on the concatenated texel inputs (so
    autograd computes the PE's input gradient too), the heads' inputs sliced from h."""
    import torch
    import torch.nn.functional as F

    texel = torch.cat(texel, dim=1)
    w, k = decoder.first.weight, texel.shape[1]
    h = F.relu(F.linear(texel, w[:, :k], torch.addmv(decoder.first.bias, w[:, k:], frame)))
    return {name: head(h[:, decoder.slices[name]]) for name, head in decoder.heads.items()}


def library_lpips():
    """ST-LPIPS in its plain form: channel-major, the library's backward for every layer."""
    from archhead_addon.train import perceptual

    class LibraryLPIPS(perceptual.ShiftTolerantLPIPS):
        def _features(self, images):
            x = ((2 * images - 1) - self.shift) / self.scale
            feats = []
            for layer in self.trunk:
                x = layer(x)
                feats.append(perceptual._unit(x))
            return feats

    return perceptual.unfolded(LibraryLPIPS())  # its first slice unfolded too


@contextlib.contextmanager
def plain_step(trainer, library):
    """The trainer with the plain step's parts (the module docstring)."""
    module, loss, decoder = avatar_module(), trainer.loss, trainer.avatar.decoder
    saved = module.texel_features, loss.perceptual
    module.texel_features = interpolated_texel_features
    loss.perceptual = library
    loss.perceptual_reference = lambda target: None  # each render computes its own
    decoder.forward = partial(concatenated_decoder_forward, decoder)
    try:
        yield
    finally:
        module.texel_features, loss.perceptual = saved
        del loss.perceptual_reference, decoder.forward


def _waiting() -> str:
    """How OpenMP threads wait in this process (threads.choose_openmp_waiting's choice)."""
    chosen = [f"{k}={os.environ[k]}" for k in WAITING if k in os.environ]
    return ", ".join(chosen) or "OpenMP's default"


def _expected(values, uses_lpips) -> float:
    """A step's expected milliseconds, robust to the machine's load: the medians of the steps
    with ST-LPIPS and of those without, weighted by their shares of the steps."""
    total = 0.0
    for want in (True, False):
        group = [v for v, u in zip(values, uses_lpips, strict=True) if u == want]
        if group:
            total += len(group) / len(values) * statistics.median(group)
    return total


def _ms(fn) -> float:
    start = time.perf_counter()
    fn()
    return 1e3 * (time.perf_counter() - start)


class Profiler:
    def __init__(self, trainer):
        import torch

        self.torch, self.trainer = torch, trainer

    def step(self, step: int) -> float:
        """Milliseconds of the trainer's `step`."""
        with self._unchanged():
            self.trainer.step = step
            return _ms(self.trainer.train_step)

    def parts(self, step: int) -> dict[str, float]:
        """Milliseconds of each part of `step`, each run alone."""
        with self._unchanged():
            return self._parts(step)

    @contextlib.contextmanager
    def _unchanged(self):
        """Leaves the avatar and Adam as they were, so that every step and part starts from
        the same avatar (training an untrained one grows its Gaussians over the first steps,
        and the kernel's time with them; the parts' stand-in losses did that tenfold)."""
        t = self.trainer
        saved = copy.deepcopy((t.avatar.state_dict(), t.optimizer.state_dict()))
        yield
        t.avatar.load_state_dict(saved[0])
        t.optimizer.load_state_dict(saved[1])

    def _parts(self, step: int) -> dict[str, float]:
        torch, t = self.torch, self.trainer
        avatar, cfg = t.avatar, t.config
        out = dict.fromkeys(PARTS, 0.0)
        box = {}
        out["data"] = _ms(
            lambda: box.update(frame=t.frames[t.frame_index(step)], lods=t.lods(step))
        )
        frame, lods = box["frame"], box["lods"]
        h, w = frame.image.shape[:2]
        lpips = cfg.loss.lpips > 0 and step % cfg.lpips_every == 0
        for lod in lods:
            lv = avatar.level(resolution_for_lod(lod, avatar.config.s_max, avatar.config.s_min)[1])

            def resample(lv=lv):
                feat = avatar_module().texel_features(avatar.features, lv["resample"], lv["texel"])
                feat.backward(torch.ones_like(feat))

            resample_ms = _ms(resample)
            out["resample"] += resample_ms

            def decode(lod=lod):
                g = avatar(lod, **frame.codes)
                loss = sum(
                    getattr(g, k).square().mean()
                    for k in ("means", "quats", "log_scales", "opacity_logits", "sh", "offsets")
                )
                loss.backward()
                box["g"] = g

            out["decoder"] += _ms(decode) - resample_ms
            g = box["g"]
            leaves = [
                x.detach().requires_grad_()
                for x in (g.means, g.quats, g.log_scales, g.opacity_logits, g.sh)
            ]

            def splat(leaves=leaves):
                rgb = _render(t, leaves, frame, w, h)
                (rgb - frame.image).square().mean().backward()
                box["rgb"] = rgb.detach()

            out["kernel"] += _ms(splat)
            if lpips:
                pred = box["rgb"].requires_grad_()

                def perceptual(pred=pred):
                    nchw = [x.permute(2, 0, 1)[None] for x in (pred, frame.image)]
                    t.loss.perceptual(*nchw)[0].backward()

                out["ST-LPIPS"] += _ms(perceptual)
        out["Adam"] = _ms(t.optimizer.step)
        t.optimizer.zero_grad(set_to_none=True)
        return out


def avatar_module():
    from archhead_addon.avatar import model

    return model


def _render(trainer, leaves, frame, w, h):
    from archhead_addon.splat import rasterization

    means, quats, log_scales, opacity_logits, sh = leaves
    return rasterization(
        means,
        quats,
        log_scales,
        opacity_logits,
        sh,
        frame.w2c,
        frame.K,
        w,
        h,
        background=trainer.background,
        num_threads=trainer.config.threads,
    ).rgb


def training_setup(args):
    """(config, dataset, frames in memory) of `args.config` on `args.data`, with
    `args.threads` threads (the process restarts itself with the thread variables set)."""
    keep_freed_memory()  # as the training command does
    choose_openmp_waiting()  # as the training command does, before torch loads
    restart_with_threads(args.threads)

    import torch

    from archhead_addon.flame.model import load_model
    from archhead_addon.train import loop
    from archhead_addon.train.config import TrainConfig
    from archhead_addon.train.dataset import FrameDataset

    torch.set_num_threads(args.threads)
    config = TrainConfig.load(args.config)
    dataset = FrameDataset(
        args.data, config.resolution, load_model(), split="train", holdout=config.holdout
    )
    return config, dataset, loop.frames_on_device(dataset, torch.device("cpu"))


def make_trainer(config, dataset, frames, avatar_path, out_dir):
    """A CPU trainer of `config` from the avatar at `avatar_path`, or an untrained one."""
    import torch

    from archhead_addon.avatar.checkpoint import load_avatar
    from archhead_addon.train import loop

    cpu, model = torch.device("cpu"), dataset.model
    if avatar_path is None:
        return loop.Trainer.create(
            config,
            frames,
            model,
            dataset.sequence.shape[0],
            out_dir,
            dataset.background,
            cpu,
            identity_offset=dataset.sequence.static_offset,
        )
    avatar = load_avatar(avatar_path, model)
    return loop.Trainer(config, frames, avatar, out_dir, dataset.background, cpu)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=DEFAULT_DATA, help="subject folder")
    p.add_argument("--config", default="cpu", help="training config file or preset")
    p.add_argument(
        "--avatar",
        type=Path,
        help="a trained avatar.npz to time (default: an untrained one of the config), which "
        "every timed step starts from: an untrained avatar's Gaussians are not a run's",
    )
    p.add_argument("--steps", type=int, default=8, help="steps per stage and variant")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    config, dataset, frames = training_setup(args)

    import torch

    with tempfile.TemporaryDirectory() as tmp:  # nothing is saved: the steps are called alone
        trainer = make_trainer(config, dataset, frames, args.avatar, tmp)
    library = library_lpips() if trainer.loss.perceptual is not None else None
    variants = {
        "before": partial(plain_step, trainer, library),
        "after": contextlib.nullcontext,
    }
    profiler = Profiler(trainer)
    print(
        f"# Training-step profile: {args.data} ({len(frames)} training frames, "
        f"{dataset.size[0]}x{dataset.size[1]} px), "
        f"config {args.config}, avatar {args.avatar or 'untrained'}, "
        f"{torch.get_num_threads()} threads, {args.steps} steps per stage and variant; "
        f"OpenMP waiting: {_waiting()}; load average {os.getloadavg()[0]:.2f}\n"
    )
    cycle = max(config.lpips_every, 1)  # whole cycles: as many ST-LPIPS steps as training
    steps = -(-args.steps // cycle) * cycle
    expected, paired = {}, {}
    for stage, first in ((1, 0), (2, config.stage1_steps)):
        times = {v: {k: [] for k in ("step", *PARTS)} for v in variants}
        for i in range(-1, steps):  # i = -1: an untimed warm-up of each variant
            step = first + max(i, 0)
            for name, variant in variants.items():
                with variant():
                    step_ms = profiler.step(step)
                    parts = profiler.parts(step)
                if i >= 0:
                    times[name]["step"].append(step_ms)
                    for k, v in parts.items():
                        times[name][k].append(v)
        uses = [config.loss.lpips > 0 and (first + i) % cycle == 0 for i in range(steps)]
        expected[stage] = {
            v: {k: _expected(x, uses) for k, x in t.items()} for v, t in times.items()
        }
        paired[stage] = {}
        for k in ("step", *RATIOS):  # over the steps that have the part (ST-LPIPS: 1 in 4)
            pairs = zip(times["before"][k], times["after"][k], strict=True)
            ratios = [b / a for b, a in pairs if a > 0]
            if ratios:
                paired[stage][k] = statistics.median(ratios)
    print(
        f"Milliseconds per step, {steps} steps per stage: the medians of the steps with "
        f"ST-LPIPS ({steps // cycle}) and without, weighted as training takes them:\n"
    )
    print("| stage | version | step | " + " | ".join(PARTS) + " | other |")
    print("|---|---|---:|" + "---:|" * (len(PARTS) + 1))
    for stage, by_variant in expected.items():
        for name, m in by_variant.items():
            other = m["step"] - sum(m[k] for k in PARTS)
            cells = " | ".join(f"{m[k]:.1f}" for k in ("step", *PARTS))
            print(f"| {stage} | {name} | {cells} | {other:.1f} |")
    print(
        "\nbefore / after, the median of the per-step ratios (each step run both ways, "
        "back to back):\n"
    )
    for stage, r in paired.items():
        b, a = expected[stage]["before"], expected[stage]["after"]
        cells = [
            f"{k} {r[k]:.2f}x ({b[k]:.{0 if k == 'step' else 1}f} -> "
            f"{a[k]:.{0 if k == 'step' else 1}f} ms)"
            for k in ("step", *RATIOS)
            if k in r
        ]
        print(f"- stage {stage}: " + ", ".join(cells))
    weights = {1: config.stage1_steps, 2: config.stage2_steps}
    for name in variants:
        mean = sum(w * expected[s][name]["step"] for s, w in weights.items()) / sum(
            weights.values()
        )
        print(f"- {name}: {mean:.0f} ms per step over the config's stages")
    ms, mb = checkpoint_cost(trainer, args.data.parent)
    every = config.checkpoint_every
    print(
        f"- a checkpoint: {ms:.0f} ms, {mb:.1f} MB written (the median of {SAVES}); every "
        f"{every} steps ({config.total_steps // every} in the run): {ms / every:.2f} ms a step"
    )


SAVES = 5


def checkpoint_cost(trainer, where: Path) -> tuple[float, float]:
    """(median ms, MB) of the trainer's checkpoint as training writes it (every file atomic,
    fsynced), into a folder on the filesystem of `where`, as a run beside its data; after a
    step kept, so that Adam's moments are in it, as in a run (the timed steps are undone)."""
    trainer.train_step()
    with tempfile.TemporaryDirectory(dir=where) as tmp:
        trainer.out_dir = Path(tmp)
        trainer.write_config()
        times = []
        for _ in range(SAVES):
            start = time.perf_counter()
            trainer.save()
            times.append((time.perf_counter() - start) * 1e3)
        size = sum(f.stat().st_size for f in Path(tmp).iterdir()) / 1e6
    return statistics.median(times), size


if __name__ == "__main__":
    main()
