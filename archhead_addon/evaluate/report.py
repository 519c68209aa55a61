"""Tables (Markdown, CSV) and the error-against-run-time plot of an evaluation."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from ..io.atomic import atomic_path, write_bytes_atomic
from .lods import LodResult

COLUMNS = (
    "lod",
    "precision",
    "uv_resolution",
    "gaussians",
    "l1",
    "psnr",
    "ssim",
    "st_lpips",
    "decode_ms",
    "splat_ms",
    "render_ms",
    "psnr_head",
    "ssim_head",
    "st_lpips_head",
    "psnr_face",
    "needles",
    "rods",
    "black",
)
# Paper section 4.4: LOD 1 against LOD 0 (Gaussians, PSNR, SSIM, FPS) on its GPUs.
PAPER_RATIOS = {
    "gaussians": "6.2 %",
    "psnr": "-0.97 %",
    "ssim": "-0.6 %",
    "speed": "1.96x (+96 % FPS)",
}


def _row(r: LodResult) -> dict:
    return {
        "lod": r.lod,
        "precision": r.precision,
        "uv_resolution": r.resolution,
        "gaussians": r.gaussians,
        "l1": r.l1,
        "psnr": r.psnr,
        "ssim": r.ssim,
        "st_lpips": r.st_lpips,
        "decode_ms": r.decode_ms,
        "splat_ms": r.splat_ms,
        "render_ms": r.render_ms,
        "psnr_head": r.psnr_head,
        "ssim_head": r.ssim_head,
        "st_lpips_head": r.st_lpips_head,
        "psnr_face": r.psnr_face,
        "needles": r.needles,
        "rods": r.rods,
        "black": r.black,
    }


def to_csv(results: list[LodResult]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, COLUMNS, lineterminator="\n")
    writer.writeheader()
    for r in results:
        writer.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in _row(r).items()})
    return out.getvalue()


def lod_table(results: list[LodResult]) -> str:
    lines = [
        "| LOD | precision | S | Gaussians | L1 | PSNR (dB) | SSIM | ST-LPIPS | head PSNR "
        "| head SSIM | head ST-LPIPS | face PSNR | axis ratio > 10 | rods | black | decode ms "
        "| splat ms | total ms |",
        "|---" * 18 + "|",
    ]
    for r in results:
        lines.append(
            f"| {r.lod:.2f} | {r.precision} | {r.resolution} | {r.gaussians:,} | "
            f"{r.l1:.4f} | {r.psnr:.2f} | {r.ssim:.4f} | {r.st_lpips:.4f} | "
            f"{r.psnr_head:.2f} | {r.ssim_head:.4f} | {r.st_lpips_head:.4f} | "
            f"{r.psnr_face:.2f} | {100 * r.needles:.1f} % | {100 * r.rods:.1f} % | "
            f"{100 * r.black:.1f} % | "
            f"{r.decode_ms:.1f} | {r.splat_ms:.1f} | {r.render_ms:.1f} |"
        )
    return "\n".join(lines)


def lod_ratios(results: list[LodResult], precision: str = "fp32") -> dict[str, float]:
    """LOD 1 against LOD 0: Gaussian fraction, relative PSNR / SSIM change, speed-up."""
    by_lod = {r.lod: r for r in results if r.precision == precision}
    if 0.0 not in by_lod or 1.0 not in by_lod:
        raise ValueError("the LOD 1 : LOD 0 ratios need both levels evaluated")
    low, high = by_lod[1.0], by_lod[0.0]
    return {
        "gaussians": low.gaussians / high.gaussians,
        "psnr": low.psnr / high.psnr - 1,
        "ssim": low.ssim / high.ssim - 1,
        "speed": high.render_ms / low.render_ms,
    }


def ratio_table(results: list[LodResult], precision: str = "fp32") -> str:
    ours = lod_ratios(results, precision)
    return "\n".join(
        [
            f"| LOD 1 vs LOD 0 ({precision}) | here | paper |",
            "|---|---|---|",
            f"| Gaussians | {100 * ours['gaussians']:.1f} % | {PAPER_RATIOS['gaussians']} |",
            f"| PSNR | {100 * ours['psnr']:+.2f} % | {PAPER_RATIOS['psnr']} |",
            f"| SSIM | {100 * ours['ssim']:+.2f} % | {PAPER_RATIOS['ssim']} |",
            f"| render speed | {ours['speed']:.2f}x | {PAPER_RATIOS['speed']} |",
        ]
    )


def write_tables(folder: Path, results: list[LodResult], title: str) -> None:
    """metrics.csv and metrics.md (with the ratios when LOD 0 and LOD 1 were evaluated)."""
    write_bytes_atomic(folder / "metrics.csv", to_csv(results).encode())
    text = f"# {title}\n\n{lod_table(results)}\n"
    levels = {(r.lod, r.precision) for r in results}
    precision = results[0].precision
    if {(0.0, precision), (1.0, precision)} <= levels:
        text += f"\n{ratio_table(results, precision)}\n"
    write_bytes_atomic(folder / "metrics.md", text.encode())


def plot_error_vs_time(path: Path, results: list[LodResult], title: str) -> None:
    """PSNR and L1 against render time, one line per precision, points labelled by LOD."""
    series = {
        precision: [(r.lod, r.render_ms, r.psnr, r.l1) for r in results if r.precision == precision]
        for precision in ("fp32", "fp16")
    }
    plot_psnr_l1_against_ms(path, series, "ms per frame (numpy decode + CPU splat)", title)


def plot_psnr_l1_against_ms(path: Path, series: dict, xlabel: str, title: str, labelled=None):
    """Two panels, PSNR and L1 against milliseconds: `series` maps a precision to its points
    (lod, ms, psnr, l1); fp32's points are labelled by LOD (those `labelled(lod)` accepts)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6), layout="constrained")
    for precision, marker in (("fp32", "o"), ("fp16", "s")):
        points = series.get(precision) or []
        if not points:
            continue
        lods, times, psnrs, l1s = zip(*points, strict=True)
        for ax, values in zip(axes, (psnrs, l1s), strict=True):
            ax.plot(times, values, marker=marker, markersize=3, label=precision)
            if precision != "fp32":
                continue
            for lod, t, v in zip(lods, times, values, strict=True):
                if labelled is None or labelled(lod):
                    ax.annotate(
                        f"LOD {lod:g}",
                        (t, v),
                        fontsize=7,
                        textcoords="offset points",
                        xytext=(4, 4),
                    )
    axes[0].set_ylabel("test PSNR (dB), higher is better")
    axes[1].set_ylabel("test L1, lower is better")
    for ax in axes:
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title, fontsize=9)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)
    plt.close(fig)
