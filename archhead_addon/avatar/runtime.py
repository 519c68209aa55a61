"""The avatar in numpy alone (for Blender): reads a checkpoint and decodes frames into Gaussians,
reproducing `model.ArchHeadAvatar` (see its docstring for the network). Never imports torch.

Per resolution S (`level(S, precision)`, least recently used out first once their bytes pass
`level_bytes`: a crowd of heads shares one runtime, each at its own S): the UV table, the
texels' face corners and base log scale, and the feature field resampled to S, blended, and
pushed through the feature columns of the fused first layer, `W1_feature @ feature`
(fused width, N). A frame then costs FLAME, the position map, the PE and the MLPs; the driving
code and l are the same for every texel, so they enter the first layer as one bias column
(multiplying a constant row appended to the PE). The texels go through the network in
chunks, several at once on `threads` threads, each with one BLAS thread (`_Network`), and
each chunk's Gaussians are finished on the thread that decoded it.

fp16 path, storage only: weights, cached per-S terms, activations and raw outputs are held
in half precision (as a half-precision GPU decoder holds them), every product and sum runs in
float32. numpy has no half-precision arithmetic and converts element by element, so the path
halves the per-S cache and costs time, 3-5x the fp32 decode (docs/bench_decode.md): it
is there to measure what half precision costs in accuracy (`precision_error`), not to speed
a display up.
"""

from __future__ import annotations

import functools
import math
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from typing import NamedTuple

import numpy as np

from ..flame.lbs import forward_full
from ..rotations import axis_angle_to_matrix, axis_angle_to_quaternion
from ..threads import one_blas_thread, thread_count
from ..uv.raster import UVRaster, face_texel_scale
from .bicubic import resize
from .checkpoint_format import AvatarCheckpoint, checkpoint_mesh, read_checkpoint
from .config import EYES_DIM, HEADS, JAW_DIM, QUAT_EPS
from .culling import ViewFrustum, reach
from .gaussians import Gaussians, quat_multiply
from .identity import bake_identity
from .level_cache import LEVEL_BYTES, LevelCache
from .lod import blend_weights, resolution_for_lod

F32, F16 = np.float32, np.float16
PRECISIONS = ("fp32", "fp16")
CHUNK = 8192  # most texels per pass through the decoder (its widest activations stay in cache)
# Culling pays when it leaves out more than this share's complement: below, the gathers of
# the kept texels cost about what decoding the others would.
CULL_WORTH = 0.9


class AvatarRuntime:
    def __init__(
        self,
        ckpt: AvatarCheckpoint,
        flame=None,
        path=None,
        level_bytes: int = LEVEL_BYTES,
        threads: int = 0,
    ):
        """`threads`: how many threads decode chunks of texels at once (0: every core);
        `level_bytes`: how much the per-S tables may hold (`LevelCache`)."""
        self.config = cfg = ckpt.config
        self.threads = thread_count(threads)
        self.mesh = checkpoint_mesh(ckpt, flame, path)
        self.head = bake_identity(self.mesh, ckpt.identity_shape, ckpt.identity_offset)
        self.raster = UVRaster(self.mesh.uv, self.mesh.uv_faces)
        self.face_scale = face_texel_scale(
            self.mesh.v_template, self.mesh.faces, self.mesh.uv, self.mesh.uv_faces
        )
        self.features = {s: ckpt.params[f"features.{s}"] for s in cfg.levels}
        self._nets = {p: _Network(ckpt.params, cfg, half=p == "fp16") for p in PRECISIONS}
        # Through a weak reference: a cached bound method is a cycle (self -> cache -> self)
        # that only the cyclic collector frees, and a dropped runtime would keep hundreds of
        # MB until it ran (Blender's deleted avatars).
        this = weakref.ref(self)
        self.level = LevelCache(
            lambda size, precision: this()._build_level(size, precision), level_bytes
        )

    @classmethod
    def load(
        cls, path, flame=None, level_bytes: int = LEVEL_BYTES, threads: int = 0
    ) -> AvatarRuntime:
        """`flame`: the FLAME model the avatar was trained on (FlameModel, file, None=built-in)."""
        return cls(read_checkpoint(path), flame, path, level_bytes, threads)

    def resolution(self, lod: float) -> int:
        return resolution_for_lod(lod, self.config.s_max, self.config.s_min)[1]

    def _build_level(self, size: int, precision: str) -> dict:
        table = self.raster.table(size)
        net = self._nets[precision]
        level = {
            "texel": table.texel,
            "vert_idx": self.mesh.faces[table.face],
            "bary": table.bary.astype(F32),
            "base_log_scale": np.log(self.face_scale[table.face] / size)[None].astype(F32),
        }
        if self.config.levels:
            fmap = sum(
                F32(w) * resize(self.features[s], size)
                for w, s in zip(
                    blend_weights(self.config.levels, size, self.config.tau),
                    self.config.levels,
                    strict=True,
                )
            )
            level["first"] = net.feature_term(fmap.reshape(len(fmap), -1)[:, table.texel])
        return level

    def decode(
        self,
        lod: float = 0.0,
        *,
        expr=None,
        jaw=None,
        neck=None,
        eyes=None,
        rotation=None,
        translation=None,
        precision: str = "fp32",
        sh_degree: int | None = None,
        view: ViewFrustum | None = None,
        posed: PosedHead | None = None,
    ) -> Gaussians:
        """Gaussians of one frame (numpy arrays). Codes are 1-D; absent ones are zero.
        `sh_degree` below the avatar's decodes only those bands (a display that shows the
        DC colour asks for 0: the other rows of the colour head are never computed).
        `view` leaves out the texels that camera cannot see (culling.py) before decoding.
        `posed`: this frame's head from `pose`, where several frames were posed at once."""
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        cfg, net = self.config, self._nets[precision]
        degree = cfg.sh_degree if sh_degree is None else min(int(sh_degree), cfg.sh_degree)
        if degree < 0:
            raise ValueError(f"sh_degree must be >= 0, got {sh_degree}")
        l, size = resolution_for_lod(lod, cfg.s_max, cfg.s_min)
        level = self.level(size, precision)
        # The whole frame with BLAS held to one thread where the chunks decode on threads of
        # their own: OpenBLAS threads that FLAME's products woke kept spinning after them and
        # slowed render loops (benchmarks/avatar_decode.py, docs/bench_decode.md). On a
        # thread of `decode_batch`, which holds BLAS itself, the frame decodes on that thread.
        batched = getattr(_BATCH, "blas_held", None)
        if batched is not None:
            hold, threads = nullcontext(batched), 1
        else:
            hold = one_blas_thread() if self.threads > 1 else nullcontext(False)
            threads = self.threads
        with hold as held:
            if posed is None:
                posed = self.pose([{"expr": expr, "jaw": jaw, "neck": neck, "eyes": eyes}])[0]
            rot = _code(rotation, 3, "rotation")
            rot_m = axis_angle_to_matrix(rot).astype(F32)
            j0 = posed.joint[:, None]
            shift = j0 + _code(translation, 3, "translation").astype(F32)[:, None]
            # channel-major (3, N) from here on: every row a contiguous attribute
            pos = np.einsum("nk,nkc->cn", level["bary"], posed.vertices[level["vert_idx"]])
            columns = None  # the texels decoded: all, or those the view keeps
            if view is not None:
                if "reach" not in level:
                    level["reach"] = self._reach(l, precision)
                keep = np.flatnonzero(view.visible(rot_m @ (pos - j0) + shift, level["reach"]))
                if len(keep) < CULL_WORTH * pos.shape[1]:
                    columns = keep
                    level = {
                        k: a if k == "first" else a[..., keep] if k == "base_log_scale" else a[keep]
                        for k, a in level.items()
                    }
                    pos = pos[:, keep]
            drive_in = np.concatenate(
                [
                    _code(expr, cfg.n_expr, "expr", pad=True),
                    _code(jaw, JAW_DIM, "jaw"),
                    _code(eyes, EYES_DIM, "eyes"),
                ]
            )
            frame = _FrameOutputs(
                cfg, pos, level["base_log_scale"], rot, rot_m, j0, shift, 3 * (degree + 1) ** 2
            )
            net.decode(
                pos,
                level.get("first"),
                net.frame_bias(drive_in, l),
                frame.colour_rows,
                frame.write,
                columns=columns,
                threads=threads if held else 1,
                row_by_row=held,
            )
        return frame.gaussians(level["texel"], size)

    def pose(self, codes: list[dict]) -> list[PosedHead]:
        """FLAME posed by each of several code sets (`decode`'s expr, jaw, neck and eyes;
        absent ones zero) in one batched pass: a crowd's heads share one product with the
        expression basis and the Python around it, a far head's largest fixed cost
        (benchmarks/crowd.py). Expressions of different widths are zero-padded."""
        if not codes:
            return []
        width = max((np.size(c["expr"]) for c in codes if c.get("expr") is not None), default=0)
        batch = {
            name: np.stack([_code(c.get(name), size, name) for c in codes])
            for name, size in (("neck", 3), ("jaw", JAW_DIM), ("eyes", EYES_DIM))
        }
        if width:
            batch["expr"] = np.stack([_code(c.get("expr"), width, "expr", pad=True) for c in codes])
        head = forward_full(self.head, dtype=F32, **batch)
        return [PosedHead(v, j[0]) for v, j in zip(head.vertices, head.joints, strict=True)]

    def _reach(self, lod: float, precision: str) -> np.ndarray:
        """How far each texel's Gaussian reaches from its surface point (culling.reach), from
        the neutral frame at this level: offsets model mostly static shape (hair on a
        real subject lies up to 10 cm off the head), which expressions move little."""
        g = self.decode(lod, precision=precision)
        return reach(g.offsets, g.log_scales)

    def precision_error(self, lod: float = 0.0, **codes) -> dict[str, float]:
        """Largest absolute difference of every attribute, fp16 path against fp32."""
        full = self.decode(lod, precision="fp32", **codes)
        half = self.decode(lod, precision="fp16", **codes)
        names = ("means", "log_scales", "quats", "opacity_logits", "sh")
        return {k: float(np.abs(getattr(full, k) - getattr(half, k)).max()) for k in names}


class PosedHead(NamedTuple):
    """One frame's posed FLAME head, before the global rotation and translation."""

    vertices: np.ndarray  # (V,3) float32
    joint: np.ndarray  # (3,) float32: the root joint, which the global rotation turns about


class _Network:
    """The mapping network and the decoder, in torch's (out, in) weight layout.

    Activations are channel-major (channels, texels), the shape in which BLAS runs these
    long, thin products fastest here, and go through the decoder in chunks of texels so
    the first layer's wide activations stay in cache. The chunks are independent, and numpy
    releases the GIL in its products and element-wise passes, so threads decode several at
    once: the element-wise work, a third of a decode, runs on every core too, which BLAS's
    own threads never did. With half=True the weights and every stored intermediate are
    rounded to float16 (`round`) while products accumulate in float32.
    """

    def __init__(self, params: dict[str, np.ndarray], cfg, half: bool):
        self.half = half

        def w(name):
            return np.ascontiguousarray(self.round(params[name].astype(F32)))

        def b(name):
            return self.round(params[name].astype(F32))[:, None]

        self.pe_centre = np.asarray(cfg.pe_centre, F32)[:, None]
        self.freqs = (2.0 ** np.arange(cfg.pe_freqs)).astype(F32)[:, None, None]
        self.mapping = [
            (w("mapping.0.weight"), b("mapping.0.bias")[:, 0]),
            (w("mapping.2.weight"), b("mapping.2.bias")[:, 0]),
        ]
        first = w("decoder.first.weight")  # (fused width, in_dim): PE | feature | drive | l
        n_feat = cfg.feature_dim if cfg.levels else 0
        pe = cfg.pe_dim
        self.w_pe = first[:, :pe]
        self.w_feature = np.ascontiguousarray(first[:, pe : pe + n_feat])
        self.w_drive = first[:, pe + n_feat : pe + n_feat + cfg.drive_dim]
        self.w_lod = first[:, -1]
        self.b_first = b("decoder.first.bias")[:, 0]
        self.slices = cfg.head_slices()
        self.layers = {
            name: (
                [
                    (
                        w(f"decoder.heads.{name}.hidden.{i}.weight"),
                        b(f"decoder.heads.{name}.hidden.{i}.bias"),
                    )
                    for i in range(cfg.head_layers - 1)
                ],
                (w(f"decoder.heads.{name}.out.weight"), b(f"decoder.heads.{name}.out.bias")),
            )
            for name in HEADS
        }

    def round(self, x: np.ndarray) -> np.ndarray:
        """x as the path holds it: unchanged (fp32) or rounded to float16 (kept in float32
        so that BLAS does the products)."""
        return x.astype(F16).astype(F32) if self.half else x

    def store(self, x: np.ndarray) -> np.ndarray:
        """A cached array in the path's storage type (half the memory for fp16)."""
        return x.astype(F16) if self.half else x

    def feature_term(self, feat: np.ndarray) -> np.ndarray:
        """The per-resolution part of the first layer, W1_feature @ feature (fused, N)."""
        return self.store(self.w_feature @ self.round(feat))

    def frame_bias(self, drive_in: np.ndarray, lod: float) -> np.ndarray:
        """The first layer's per-frame constant: W_drive @ drive + l * w_l + b (fused,)."""
        (w0, b0), (w1, b1) = self.mapping
        hidden = np.maximum(w0 @ self.round(drive_in.astype(F32)) + b0, 0)
        drive = self.round(np.tanh(w1 @ self.round(hidden) + b1))
        return self.round(self.w_drive @ drive + F32(lod) * self.w_lod + self.b_first)

    def encode(self, pos: np.ndarray) -> np.ndarray:
        """(pe_dim + 1, n) float32 from positions (3, n): p, sin(2^k p), cos(2^k p) (k-major,
        then x, y, z), and a row of ones that carries the first layer's per-frame bias."""
        n, k = pos.shape[1], 3 * len(self.freqs)
        out = np.empty((3 + 2 * k + 1, n), F32)
        p = out[:3]
        np.subtract(pos, self.pe_centre, out=p)
        # The angles in an array of their own: a ufunc whose input and output are views of
        # one array takes numpy's overlap-safe path, 10x slower for sin and cos.
        angles = (self.freqs * p[None]).reshape(-1, n)
        np.sin(angles, out=out[3 : 3 + k])
        np.cos(angles, out=out[3 + k : 3 + 2 * k])
        out[-1] = 1.0
        return self.round(out)

    def decode(
        self,
        pos: np.ndarray,
        first,
        frame_bias: np.ndarray,
        colour_rows: int,
        write,
        columns=None,
        threads: int = 1,
        row_by_row: bool = False,
    ) -> None:
        """The heads' raw outputs from the texels' positions (3, N), chunk by chunk: each
        chunk's, (width, n) per head, go to write(texel slice, outputs), on the thread that
        decoded them. The colour head's first `colour_rows` outputs only (its SH
        coefficients are coefficient-major). `columns`: the texels of `first` that the
        positions are (culling), gathered chunk by chunk rather than copied whole.
        `threads` decode chunks at once, each product on one BLAS thread: more than one only
        while the caller holds BLAS to one thread (`one_blas_thread`), as `row_by_row` says
        it does."""
        w_in = np.hstack([self.w_pe, frame_bias[:, None]])
        layers = dict(self.layers)
        hidden, (w_out, b_out) = layers["colour"]
        layers["colour"] = (hidden, (w_out[:colour_rows], b_out[:colour_rows]))

        def chunk(cols: slice) -> None:
            h = w_in @ self.encode(pos[:, cols])
            if first is not None:
                h += first[:, cols] if columns is None else first[:, columns[cols]]
            _relu_(h)
            h = self.round(h)
            raw = {}
            for name, (hidden, (w_out, b_out)) in layers.items():
                x = h[self.slices[name]]
                for w, b in hidden:
                    x = w @ x
                    x += b
                    _relu_(x)
                    x = self.round(x)
                y = out_product(w_out, x)
                y += b_out
                raw[name] = self.round(y)
            write(cols, raw)

        # On `threads` threads; in this thread alone, with BLAS threading each product, where
        # BLAS cannot be held to one.
        out_product = _row_by_row if row_by_row else np.matmul
        if threads > 1:
            for _ in _pool(threads).map(chunk, _chunks(pos.shape[1], threads)):
                pass  # (raises a worker's exception)
        else:
            for cols in _chunks(pos.shape[1], 1):
                chunk(cols)


class _FrameOutputs:
    """A frame's Gaussians, texel-major as `Gaussians` holds them, written chunk by chunk
    from the heads' raw, channel-major outputs: on the decoding threads, which share this
    element-wise work too."""

    def __init__(self, cfg, pos, base_log_scale, rot, rot_m, j0, shift, colour_rows: int):
        n = pos.shape[1]
        self.cfg, self.pos, self.base_log_scale = cfg, pos, base_log_scale
        self.rot_m, self.j0, self.shift = rot_m, j0, shift
        self.rot_q = axis_angle_to_quaternion(rot).astype(F32)
        self.colour_rows = colour_rows
        self.arrays = {
            name: np.empty((n, width), F32)
            for name, width in (
                ("means", 3),
                ("log_scales", 3),
                ("quats", 4),
                ("opacity_logits", 1),
                ("sh", colour_rows),
                ("offsets", 3),
            )
        }

    def write(self, cols: slice, raw: dict[str, np.ndarray]) -> None:
        cfg, out = self.cfg, self.arrays
        offsets = F32(cfg.offset_unit) * raw["offset"]
        out["offsets"][cols] = offsets.T
        out["means"][cols] = (self.rot_m @ (self.pos[:, cols] + offsets - self.j0) + self.shift).T
        q = raw["rotation"]
        norm = np.sqrt(np.einsum("in,in->n", q, q))
        q = np.where(norm > QUAT_EPS, q / np.maximum(norm, QUAT_EPS), F32([[1], [0], [0], [0]]))
        out["quats"][cols] = quat_multiply(self.rot_q, q.T)
        log_scales = self.base_log_scale[:, cols] + raw["scale"]
        out["log_scales"][cols] = np.clip(log_scales, cfg.log_scale_min, cfg.log_scale_max).T
        out["opacity_logits"][cols] = raw["opacity"].T
        out["sh"][cols] = raw["colour"].T

    def gaussians(self, texel: np.ndarray, size: int) -> Gaussians:
        out = self.arrays
        return Gaussians(
            means=out["means"],
            log_scales=out["log_scales"],
            quats=out["quats"],
            opacity_logits=out["opacity_logits"][:, 0],
            # -1 cannot be inferred from an empty array: a head culled whole keeps its width
            sh=out["sh"].reshape(len(texel), out["sh"].shape[1] // 3, 3),
            offsets=out["offsets"],
            uv_texel=texel,
            resolution=size,
        )


_BATCH = threading.local()  # on decode_batch's threads: whether it holds BLAS to one thread


def decode_batch(jobs: list, weights: list[float], threads: int = 0) -> list:
    """Run `jobs` (callables, each decoding one frame, say one head of a crowd, and whatever
    else it does in numpy) on `threads` threads at once, each job's decode on its own thread
    with BLAS held to one: a crowd's many small decodes keep every core busy, where one
    decode's chunks on all cores leave them waiting through FLAME, the chunks' hand-offs and
    the Python between (benchmarks/crowd.py). `weights` (texels, say) balance the threads: a
    job heavier than an equal share of what is left decodes first on every core, as it
    would alone, and the others start largest first. Returns each job's result, or the
    exception it raised, in the order of `jobs`."""
    threads = min(thread_count(threads), len(jobs))
    order = sorted(range(len(jobs)), key=lambda i: -weights[i])
    results: list = [None] * len(jobs)

    def run(i: int, held: bool | None) -> None:
        _BATCH.blas_held = held
        try:
            results[i] = jobs[i]()
        except Exception as exc:  # the caller says which job failed, and goes on with the rest
            results[i] = exc
        finally:
            _BATCH.blas_held = None

    left = float(sum(weights))
    while order and threads > 1 and weights[order[0]] * threads > left:
        left -= weights[order[0]]
        run(order.pop(0), None)  # on every core, as alone
    if threads > 1 and len(order) > 1:
        with one_blas_thread() as held:
            if held:  # (else BLAS's own threads would crowd the jobs': one at a time below)
                for _ in _pool(threads, "batch").map(lambda i: run(i, True), order):
                    pass
                return results
    for i in order:  # one at a time, each decode on every core as it would alone
        run(i, None)
    return results


def _row_by_row(w: np.ndarray, x: np.ndarray) -> np.ndarray:
    """w @ x, one matrix-vector product per row of w: 2-3x faster than OpenBLAS's matrix
    product for the heads' outputs (1-4 rows) on one BLAS thread; with several, far slower."""
    y = np.empty((len(w), x.shape[1]), F32)
    for i, row in enumerate(w):
        np.matmul(row, x, out=y[i])
    return y


def _chunks(n: int, threads: int) -> list[slice]:
    """`n` texels in equal chunks of at most CHUNK, as many as a multiple of `threads`, so
    that every thread gets the same work (LOD 1's few thousand texels included)."""
    count = threads * math.ceil(n / (CHUNK * threads))
    size = math.ceil(n / max(count, 1))
    return [slice(s, min(s + size, n)) for s in range(0, n, size)] if n else []


@functools.cache
def _pool(threads: int, kind: str = "chunks") -> ThreadPoolExecutor:
    """One pool per thread count and kind (a batch's jobs, a decode's chunks), kept for the
    process (idle threads cost nothing)."""
    return ThreadPoolExecutor(threads, thread_name_prefix=f"archhead-decode-{kind}")


def _relu_(x: np.ndarray) -> None:
    """In-place ReLU of a contiguous float32 array, as its maximum with an array of zeros:
    numpy vectorises that loop, and not the one with the scalar 0 (4x slower here, and
    still 3x as the integer max on the float's bits that this replaced)."""
    np.maximum(x, _zeros(x.size).reshape(x.shape), out=x)


@functools.lru_cache(maxsize=16)
def _zeros(size: int) -> np.ndarray:
    """Read-only zeros, one array per size (a decode's chunks and layers take a few)."""
    zeros = np.zeros(size, F32)
    zeros.flags.writeable = False
    return zeros


def _code(value, width: int, name: str, pad: bool = False) -> np.ndarray:
    """A 1-D float64 code of `width` (zeros if absent; shorter expressions zero-padded)."""
    if value is None:
        return np.zeros(width)
    v = np.asarray(value, np.float64).reshape(-1)
    if len(v) > width or (len(v) < width and not pad):
        raise ValueError(
            f"code '{name}': {len(v)} values, the avatar takes {'at most ' if pad else ''}{width}"
        )
    if not np.isfinite(v).all():
        raise ValueError(f"code '{name}' contains NaN or Inf")
    if len(v) == width:  # (np.pad costs 25 us: nine of them were a tenth of a far head's decode)
        return v
    out = np.zeros(width)
    out[: len(v)] = v
    return out
