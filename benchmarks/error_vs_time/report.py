"""The report's Markdown and figures."""

from __future__ import annotations

from pathlib import Path

from archhead_addon.evaluate.lods import LodResult
from archhead_addon.evaluate.report import plot_psnr_l1_against_ms
from archhead_addon.io.atomic import atomic_path

from .stability import StabilityRow
from .sweep import KERNEL_SIZE, LodRow

# LOD 1 against LOD 0 in the paper: table 3 (Gaussians) and section 4.4 / table 4 (the rest).
PAPER_RATIOS = {
    "Gaussians": "6.2 %",
    "L1": "+7.9 %",
    "PSNR": "-0.97 %",
    "SSIM": "-0.6 %",
    "ST-LPIPS": "+24.1 % (LPIPS)",
    "frames per second": "+96 %",
}
# Table 4 of the paper (its subjects, its GPU budget): L1, PSNR, SSIM, LPIPS at LOD 0, 0.5, 1.
PAPER_ABLATIONS = {
    "full (multi-level)": (
        (0.038, 28.621, 0.928, 0.058),
        (0.039, 28.514, 0.927, 0.061),
        (0.041, 28.342, 0.922, 0.072),
    ),
    "no feature map": (
        (0.044, 27.815, 0.913, 0.074),
        (0.044, 27.864, 0.914, 0.074),
        (0.048, 27.436, 0.907, 0.087),
    ),
    "single map 64": (
        (0.041, 28.295, 0.913, 0.063),
        (0.040, 28.391, 0.915, 0.065),
        (0.041, 28.321, 0.921, 0.075),
    ),
    "single map 128": (
        (0.041, 28.289, 0.916, 0.062),
        (0.041, 28.423, 0.917, 0.065),
        (0.042, 28.191, 0.912, 0.074),
    ),
    "single map 256": (
        (0.039, 28.614, 0.926, 0.059),
        (0.039, 28.411, 0.924, 0.064),
        (0.041, 28.323, 0.923, 0.074),
    ),
}
ABLATION_LODS = (0.0, 0.5, 1.0)


def lod_table(rows: list[LodRow], update_ms: dict[float, float]) -> str:
    lines = [
        f"| l | S | Gaussians | of l = 0 | decode ms fp32 | decode ms fp16 | kernel ms "
        f"{KERNEL_SIZE}² | Blender update ms | frame ms | L1 | PSNR dB | SSIM | "
        "ST-LPIPS | PSNR fp16 |",
        "|" + "---:|" * 14,
    ]
    top = rows[0].fp32.gaussians
    for row in rows:
        a, h = row.fp32, row.fp16
        update = update_ms.get(row.lod)
        lines.append(
            f"| {a.lod:.2f} | {a.resolution} | {a.gaussians:,} | {100 * a.gaussians / top:.1f} %"
            f" | {row.decode_ms['fp32']:.1f} | {row.decode_ms['fp16']:.1f} | {row.kernel_ms:.1f} | "
            f"{'-' if update is None else f'{update:.0f}'} | {row.frame_ms:.0f} | {a.l1:.4f} | "
            f"{a.psnr:.2f} | {a.ssim:.4f} | {a.st_lpips:.4f} | {h.psnr:.2f} |"
        )
    return "\n".join(lines)


def ratios(rows: list[LodRow]) -> dict[str, float]:
    """LOD 1 against LOD 0 (fp32), as fractions: the Gaussian count's share, the others'
    relative change (frames per second from `frame_ms`)."""
    high, low = rows[0], rows[-1]
    if high.lod != 0.0 or low.lod != 1.0:
        raise ValueError("the ratios need the sweep to run from LOD 0 to LOD 1")
    a, b = high.fp32, low.fp32
    return {
        "Gaussians": b.gaussians / a.gaussians,
        "L1": b.l1 / a.l1 - 1,
        "PSNR": b.psnr / a.psnr - 1,
        "SSIM": b.ssim / a.ssim - 1,
        "ST-LPIPS": b.st_lpips / a.st_lpips - 1,
        "frames per second": high.frame_ms / low.frame_ms - 1,
    }


def ratio_table(rows: list[LodRow]) -> str:
    lines = ["| LOD 1 vs LOD 0 (fp32) | here | paper |", "|---|---:|---:|"]
    for name, value in ratios(rows).items():
        here = f"{100 * value:.1f} %" if name == "Gaussians" else f"{100 * value:+.2f} %"
        lines.append(f"| {name} | {here} | {PAPER_RATIOS[name]} |")
    return "\n".join(lines)


def smoothness_table(pairs: list[tuple[float, float, float]]) -> tuple[str, str]:
    """(table, sentence naming the largest jump)."""
    lines = ["| from l | to l | mean image change (8-bit levels) |", "|---:|---:|---:|"]
    lines += [f"| {a:.2f} | {b:.2f} | {c:.2f} |" for a, b, c in pairs]
    a, b, c = max(pairs, key=lambda p: p[2])
    mean = sum(p[2] for p in pairs) / len(pairs)
    return "\n".join(lines), (
        f"Largest jump: l = {a:.2f} -> {b:.2f}, {c:.2f} levels (mean over all steps {mean:.2f})."
    )


def stability_table(rows: list[StabilityRow]) -> str:
    lines = [
        "| case | max abs mean (m) | max abs opacity logit | max abs SH | NaN / Inf "
        "| image change (8-bit levels) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    lines += [
        f"| {r.case} | {r.max_abs['means']:.3g} | {r.max_abs['opacity_logits']:.3g} | "
        f"{r.max_abs['sh']:.3g} | {r.non_finite} | {r.image_change:.2f} |"
        for r in rows
    ]
    return "\n".join(lines)


def ablation_table(results: dict[str, tuple[list[LodResult], float]], steps: int) -> str:
    lines = [
        f"| variant | l | L1 | PSNR dB | SSIM | ST-LPIPS | paper L1 / PSNR / SSIM / LPIPS "
        f"| training s ({steps} steps) |",
        "|---|---:|---:|---:|---:|---:|---|---:|",
    ]
    for name, (evaluated, seconds) in results.items():
        for r in evaluated:
            paper = PAPER_ABLATIONS[name][ABLATION_LODS.index(r.lod)]
            lines.append(
                f"| {name} | {r.lod:.1f} | {r.l1:.4f} | {r.psnr:.2f} | {r.ssim:.4f} | "
                f"{r.st_lpips:.4f} | {' / '.join(f'{v:g}' for v in paper)} | "
                f"{seconds:.0f} |"
            )
    return "\n".join(lines)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)


def plot_error_vs_time(path: Path, rows: list[LodRow], title: str) -> None:
    """Test PSNR and L1 against one frame's run time (decode + kernel at 512²)."""
    series = {
        precision: [
            (res.lod, r.decode_ms[precision] + r.kernel_ms, res.psnr, res.l1)
            for res, r in ((getattr(r, precision), r) for r in rows)
        ]
        for precision in ("fp32", "fp16")
    }
    plot_psnr_l1_against_ms(
        path,
        series,
        f"ms per frame (numpy decode + CPU splat at {KERNEL_SIZE}²)",
        title,
        labelled=lambda lod: round(lod * 4) == lod * 4,  # 0, 0.25, ... only
    )


def plot_smoothness(path: Path, pairs: list[tuple[float, float, float]], title: str) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 3), layout="constrained")
    ax.bar(
        [(a + b) / 2 for a, b, _ in pairs],
        [c for _, _, c in pairs],
        width=0.8 * (pairs[0][1] - pairs[0][0]),
    )
    ax.set_xlabel("level of detail (between neighbouring steps)")
    ax.set_ylabel("mean image change (8-bit levels)")
    ax.grid(alpha=0.3, axis="y")
    fig.suptitle(title, fontsize=9)
    _save(fig, path)
    plt.close(fig)
