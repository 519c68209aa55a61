"""A deterministic corpus of malformed inputs for every reader ArchHead has, and the runner
that feeds them through with a time limit (tests/test_fuzz_inputs.py; the table in
docs/input_validation.md is printed by `python tests/fuzz_corpus.py`).

Each reader starts from one valid file (`SEEDS`) and gets byte-level damage (empty files,
truncation, bit flips, zeroed runs, random bytes) plus damage aware of its container: keys
dropped or given NaN, Inf, implausible or out-of-range values, wrong dtypes and shapes; npy
header bombs, zip bombs, duplicate zip members, deflate64 and encrypted members; pickle memo
bombs ("billion laughs"), deep nesting and code-execution attempts that would create a
marker file. Every file is read in a worker process under a time limit, with tracemalloc
measuring the peak allocation. Outcomes:

  error      InputError (the reader refused it, naming file and key)
  warning    read, with an InputWarning (implausible values)
  same       read, the result equal to the seed's (the damage touched nothing used)
  changed    read without a word, the result differs from the seed's (garbage let through
             where no check can tell: a flipped mantissa bit in a plausible value)
  raw        any other exception: a raw traceback
  hang       over the time limit
  alloc      a peak allocation above ALLOC_FACTOR x the input's size + ALLOC_SLACK
  nonfinite  NaN or Inf in what the reader returned
  code       the marker file exists: code from the file ran
"""

from __future__ import annotations

import collections
import functools
import json
import math
import multiprocessing
import os
import pickle
import struct
import sys
import tempfile
import time
import tracemalloc
import warnings
import zipfile
import zlib
from collections import Counter
from dataclasses import fields, is_dataclass
from pathlib import Path

import numpy as np

SEED = 16
TIME_LIMIT_S = 5.0
ALLOC_FACTOR, ALLOC_SLACK = 8, 4 << 20
OUTCOMES = ("error", "warning", "same", "changed", "raw", "hang", "alloc", "nonfinite", "code")
F32 = np.float32


# ------------------------------------------------------------------------- valid seeds


def _flame_arrays():
    sys.path.insert(0, str(Path(__file__).parent))
    from synthetic_models import random_model_arrays

    return random_model_arrays(n_verts=40, n_shape=6, n_expr=5)


def _sequence_arrays():
    rng = np.random.default_rng(1)
    n = 4
    K = np.tile([[500.0, 0, 128], [0, 500, 128], [0, 0, 1]], (n, 1, 1))
    w2c = np.tile(np.eye(4), (n, 1, 1))
    w2c[:, 2, 3] = 1.0
    return {
        "format_version": np.int64(1),
        "fps": np.float64(25),
        "frame_ids": np.arange(n, dtype=np.int64),
        "shape": rng.normal(size=(n, 6)),
        "expr": rng.normal(size=(n, 5)),
        "jaw": 0.1 * rng.normal(size=(n, 3)),
        "neck": 0.1 * rng.normal(size=(n, 3)),
        "eyes": 0.1 * rng.normal(size=(n, 6)),
        "rotation": 0.1 * rng.normal(size=(n, 3)),
        "translation": 0.01 * rng.normal(size=(n, 3)),
        "source_format": np.str_("vhap"),
        "source_path": np.str_("x"),
        "K": K,
        "w2c": w2c,
        "image_size": np.array([256, 256]),
    }


def _vhap_arrays(n=1, seed=2):
    rng = np.random.default_rng(seed)
    return {
        "shape": rng.normal(size=(6,)).astype(F32),
        "expr": rng.normal(size=(n, 5)).astype(F32),
        "rotation": 0.1 * rng.normal(size=(n, 3)).astype(F32),
        "neck_pose": 0.1 * rng.normal(size=(n, 3)).astype(F32),
        "jaw_pose": 0.1 * rng.normal(size=(n, 3)).astype(F32),
        "eyes_pose": 0.1 * rng.normal(size=(n, 6)).astype(F32),
        "translation": 0.01 * rng.normal(size=(n, 3)).astype(F32),
    }


def _vhap_transforms():
    c2w = np.eye(4)
    c2w[2, 3] = 1.0
    frames = [
        {
            "timestep_index": t,
            "camera_index": 0,
            "flame_param_path": f"flame_param/{t:05d}.npz",
            "transform_matrix": c2w.tolist(),
        }
        for t in range(2)
    ]
    return {
        "fl_x": 500.0,
        "fl_y": 500.0,
        "cx": 128.0,
        "cy": 128.0,
        "w": 256,
        "h": 256,
        "frames": frames,
    }


def _metrical_frame():
    rng = np.random.default_rng(3)
    rot6 = np.array([[1, 0, 0, 0, 1, 0]], F32)
    return {
        "flame": {
            "exp": rng.normal(size=(1, 5)).astype(F32),
            "shape": rng.normal(size=(1, 6)).astype(F32),
            "jaw": rot6,
            "eyes": np.tile(rot6, (1, 2)),
            "eyelids": np.zeros((1, 2), F32),
        },
        "opencv": {
            "R": np.eye(3, dtype=F32)[None],
            "t": np.array([[0, 0, 1]], F32),
            "K": np.array([[[500, 0, 128], [0, 500, 128], [0, 0, 1]]], F32),
        },
        "img_size": np.array([256, 256]),
        "frame_id": "00001",
        "global_step": 100,
    }


def _fht_arrays():
    rng = np.random.default_rng(5)
    return {
        "shape": rng.normal(size=(1, 6)).astype(F32),
        "exp": rng.normal(size=(1, 5)).astype(F32),
        "head_pose": np.zeros((1, 3), F32),
        "jaw_pose": 0.1 * rng.normal(size=(1, 3)).astype(F32),
        "neck_pose": np.zeros((1, 3), F32),
        "eye_pose": np.zeros((1, 6), F32),
        "cam": np.array([[0.1, 0, 0, 0, 0, 1]], F32),
        "fov": np.array([20.0], F32),
        "K": np.array([[[700, 0, 128], [0, 700, 128], [0, 0, 1]]], F32),
    }


def _clip():
    rng = np.random.default_rng(7)
    return {"exp": rng.normal(size=(5, 5)).astype(F32), "jaw": np.zeros((5, 3), F32), "fps": 30.0}


def _tiny_avatar_config():
    from archhead_addon.avatar.config import AvatarConfig

    return AvatarConfig(
        s_max=8, s_min=4, levels=(4,), feature_dim=2, n_expr=3, drive_dim=2, pe_freqs=1,
        mapping_hidden=4, hidden=4, colour_hidden=4, head_layers=1,
    )  # fmt: skip


def _checkpoint_arrays():
    from archhead_addon.avatar.checkpoint_format import AvatarCheckpoint, write_checkpoint
    from archhead_addon.avatar.config import parameter_shapes

    config = _tiny_avatar_config()
    rng = np.random.default_rng(9)
    params = {k: rng.normal(size=s).astype(F32) for k, s in parameter_shapes(config).items()}
    ckpt = AvatarCheckpoint(
        config, "m", rng.random((6, 2)), np.array([[0, 1, 2], [3, 4, 5]]), np.zeros(4), params
    )
    with tempfile.TemporaryDirectory() as tmp:
        write_checkpoint(Path(tmp) / "a.npz", ckpt)
        return Path(tmp, "a.npz").read_bytes()


def _cache_frame_bytes():
    from archhead_addon.avatar.decode_cache import DiskCache
    from archhead_addon.splat.frame import SplatFrame

    rng = np.random.default_rng(11)
    n = 30
    frame = SplatFrame(
        rng.normal(size=(n, 3)).astype(F32), rng.normal(-5, 1, (n, 3)).astype(F32),
        np.tile(F32([1, 0, 0, 0]), (n, 1)), rng.normal(size=n).astype(F32),
        rng.normal(size=(n, 16, 3)).astype(F32), 64,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        DiskCache(tmp).put("k", frame)
        return Path(tmp, "k.npz").read_bytes()


def _train_config():
    return {
        "resolution": 64, "stage1_steps": 10, "stage2_steps": 5, "lods_per_step": 3,
        "lr": {"features": 0.005, "mapping": 0.001, "decoder": 0.002}, "lr_final_ratio": 0.1,
        "loss": {"parts": 20, "lpips": 0.05, "offset": 0.001, "scale": 0.5},
        "avatar": {"s_max": 64, "s_min": 16, "levels": [32]}, "checkpoint_every": 5,
    }  # fmt: skip


def _train_state():
    """A state as Trainer.save writes it, of a tiny avatar, tensors as numpy: the model's
    tensors, Adam's groups features, mapping and decoder, the moments of the parameters that
    had a gradient, and the checksum of it all."""
    import torch

    from archhead_addon.avatar.config import parameter_shapes
    from archhead_addon.io.checksum import KEY, tree_checksum
    from archhead_addon.train.config import TrainConfig

    torch.manual_seed(0)
    config = _tiny_avatar_config()
    params = {k: torch.randn(s) for k, s in parameter_shapes(config).items()}
    opt = torch.optim.Adam(
        [
            {"params": [p.requires_grad_() for k, p in params.items() if k.startswith(g)],
             "name": g}
            for g in ("features", "mapping", "decoder")
        ]
    )  # fmt: skip
    (params["features.4"].sum() + params["mapping.0.bias"].sum()).backward()
    opt.step()
    state = {
        "format": "archhead-train-state",
        "version": 1,
        "step": 5,
        "elapsed": 1.5,
        "config": TrainConfig().to_json(),
        "model_id": "m",
        "avatar_config": config.to_json(),
        "model": {"identity_shape": torch.randn(6), **{k: v.detach() for k, v in params.items()}},
        "optimizer": opt.state_dict(),
    }
    state = _numpy_tree(state)
    return {**state, KEY: tree_checksum(state)}


def _train_state_damage(state: dict) -> list[tuple[str, dict]]:
    """What no byte damage makes: a state whose parts disagree with each other (each would
    fail in Trainer.resume or in Adam's first step), its checksum made anew, so that only
    state_file's own checks can catch it."""
    import copy

    from archhead_addon.io.checksum import KEY, tree_checksum

    out = []

    def case(label, change):
        s = copy.deepcopy(state)
        change(s)
        out.append((label, {**s, KEY: tree_checksum(s)}))

    moments = state["optimizer"]["state"]
    first = next(iter(moments))
    case("model.identity_shape dropped", lambda s: s["model"].pop("identity_shape"))
    case("model.identity_shape (2, 3)",
         lambda s: s["model"].__setitem__("identity_shape", np.zeros((2, 3))))  # fmt: skip
    case("model.mapping.0.bias wrong shape",
         lambda s: s["model"].__setitem__("mapping.0.bias", np.zeros(7, F32)))  # fmt: skip
    case("model tensor of another model", lambda s: s["model"].__setitem__("x.w", np.zeros(2)))
    case("optimizer moment wrong shape",
         lambda s: s["optimizer"]["state"][first].update(exp_avg=np.zeros(3, F32)))  # fmt: skip
    case("optimizer moment without step", lambda s: s["optimizer"]["state"][first].pop("step"))
    case("optimizer moment of no parameter",
         lambda s: s["optimizer"]["state"].update({999: {"step": np.array(1, F32)}}))  # fmt: skip
    case("optimizer group dropped", lambda s: s["optimizer"]["param_groups"].pop())
    case("optimizer groups swapped", lambda s: s["optimizer"]["param_groups"].reverse())
    case("optimizer group parameter dropped",
         lambda s: s["optimizer"]["param_groups"][2]["params"].pop())  # fmt: skip
    case("optimizer parameter listed twice",
         lambda s: s["optimizer"]["param_groups"][2]["params"].__setitem__(0, 0))  # fmt: skip
    case("refinement without its groups",
         lambda s: s.__setitem__("refinement", {"expr": np.zeros((4, 5), F32)}))  # fmt: skip
    # finite magnitudes no run reaches (state_file.PARAMETER_LIMIT, MOMENT_LIMITS)
    for value in (1e30, 2e6):
        case(f"model weight {value:g}",
             lambda s, v=value: s["model"]["mapping.0.bias"].__setitem__(0, v))  # fmt: skip
        case(f"optimizer exp_avg {value:g}",
             lambda s, v=value: s["optimizer"]["state"][first]["exp_avg"].fill(v))  # fmt: skip
    for value in (1e30, 2e12):
        case(f"optimizer exp_avg_sq {value:g}",
             lambda s, v=value: s["optimizer"]["state"][first]["exp_avg_sq"].fill(v))  # fmt: skip
    return out


def _train_state_checksum_cases(state: dict) -> list[tuple[str, dict]]:
    """A state whose checksum is not of its content: a value changed as a damaged or edited
    file changes it, plausible and finite (only the checksum tells), or the checksum of
    another state; and keys in another order, which the checksum does not count."""
    import copy

    from archhead_addon.io.checksum import KEY, tree_checksum

    out = []

    def case(label, change):
        s = copy.deepcopy(state)
        change(s)
        out.append((label, s))

    def last_bit(a):
        flat = a.reshape(-1)
        flat[0] = np.nextafter(flat[0], flat.dtype.type(np.inf))  # in the array's own dtype

    first = next(iter(state["optimizer"]["state"]))
    groups = state["optimizer"]["param_groups"]
    case("checksum of another state",
         lambda s: s.update({KEY: tree_checksum({**s, "step": s["step"] + 1})}))  # fmt: skip
    case("checksum not text", lambda s: s.update({KEY: 0}))
    case("checksum in capitals", lambda s: s.update({KEY: s[KEY].upper()}))
    case("step + 1, checksum kept", lambda s: s.update(step=s["step"] + 1))
    case("elapsed doubled, checksum kept", lambda s: s.update(elapsed=2 * s["elapsed"]))
    case("a weight's last bit, checksum kept", lambda s: last_bit(s["model"]["mapping.0.bias"]))
    case("identity_shape's last bit, checksum kept",
         lambda s: last_bit(s["model"]["identity_shape"]))  # fmt: skip
    case("Adam moment's last bit, checksum kept",
         lambda s: last_bit(s["optimizer"]["state"][first]["exp_avg_sq"]))  # fmt: skip
    case("learning rate halved, checksum kept",
         lambda s: s["optimizer"]["param_groups"][0].update(lr=0.5 * groups[0]["lr"]))  # fmt: skip
    case("config edited, checksum kept",
         lambda s: s.update(config=s["config"].replace('"seed": 0', '"seed": 1')))  # fmt: skip
    case("keys in reverse order (same content)",
         lambda s: [s.update({k: s.pop(k)}) for k in reversed(list(s))])  # fmt: skip
    return out


def _ply_bytes():
    from archhead_addon.export.ply import write_ply

    rng = np.random.default_rng(13)
    n = 20
    quats = rng.normal(size=(n, 4))
    with tempfile.TemporaryDirectory() as tmp:
        write_ply(
            Path(tmp) / "a.ply", rng.normal(size=(n, 3)), rng.normal(-5, 1, (n, 3)),
            quats / np.linalg.norm(quats, axis=1, keepdims=True), rng.normal(size=n),
            rng.normal(size=(n, 16, 3)),
        )  # fmt: skip
        return Path(tmp, "a.ply").read_bytes()


# ------------------------------------------------------------------------- serialisers


def npz_bytes(arrays: dict) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def fast_pickle(obj) -> bytes:
    """Protocol 2 without memo entries, so opcode fragments can be spliced in anywhere."""
    import io

    buf = io.BytesIO()
    p = pickle._Pickler(buf, protocol=2)
    p.fast = True
    p.dump(obj)
    return buf.getvalue()


def torch_bytes(obj) -> bytes:
    import io

    import torch

    def tensors(v):
        if isinstance(v, np.ndarray) and v.dtype.kind in "biufc":
            return torch.from_numpy(v)
        if isinstance(v, dict):
            return {k: tensors(x) for k, x in v.items()}
        return v

    buf = io.BytesIO()
    torch.save(tensors(obj), buf)
    return buf.getvalue()


SENTINEL = "__FUZZ_SENTINEL__"
_SENTINEL_OP = b"X" + struct.pack("<I", len(SENTINEL)) + SENTINEL.encode()


def _text_op(text: str) -> bytes:
    return b"X" + struct.pack("<I", len(text.encode())) + text.encode()


def laughs(levels=40, base=0) -> bytes:
    """A list holding one memoized list twice, `levels` times over: 2^levels leaves.
    `base` offsets the memo indices (from a host pickle's own)."""
    out = b"]r" + struct.pack("<I", base) + b"0"
    for i in range(1, levels + 1):
        get = b"j" + struct.pack("<I", base + i - 1)
        out += (
            b"(" + get + get + b"lr" + struct.pack("<I", base + i) + (b"0" if i < levels else b"")
        )
    return out


def code_fragments(marker: Path) -> dict[str, bytes]:
    """Opcode fragments that would create `marker` if the unpickler called what they name."""
    m = str(marker)
    call = _text_op(f"touch {m}") + b"\x85R"  # TUPLE1, REDUCE
    return {
        "os.system": b"cos\nsystem\n" + call,
        "posix.system": b"cposix\nsystem\n" + call,
        "subprocess.getoutput": b"csubprocess\ngetoutput\n" + call,
        "builtins.exec": b"cbuiltins\nexec\n" + _text_op(f"open({m!r}, 'w')") + b"\x85R",
        "builtins.open": b"cbuiltins\nopen\n" + _text_op(m) + _text_op("w") + b"\x86R",
        "INST os.system": b"(" + _text_op(f"touch {m}") + b"ios\nsystem\n",
        "numpy.load pickle": b"cnumpy\nload\n" + _text_op(m) + b"\x85R",
        "copyreg os": b"ccopyreg\n_reconstructor\ncos\nsystem\ncbuiltins\nobject\nN\x87R",
        "torch.load": b"ctorch\nload\n" + _text_op(m) + b"\x85R",
    }


def bomb_fragments() -> dict[str, bytes]:
    state = fast_pickle(
        {"_shape": (1 << 20, 1 << 20), "data": np.zeros(2), "indices": np.zeros(2, np.int64),
         "indptr": np.zeros((1 << 20) + 1, np.int8)}
    )[2:-1]  # fmt: skip
    recon = b"cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\n" + (
        b"J\x00\x00\x00\x40\x85" + _text_op("b") + b"\x87R"
    )
    return {
        "memo bomb": laughs(),
        "memo bomb, far memo indices": laughs(base=1 << 30),
        "deep nesting": b"]" * 50_000 + b"a" * 49_999,
        "sparse 2^40 dense": b"cscipy.sparse._csc\ncsc_matrix\n)\x81" + state + b"b",
        "ndarray 2^30 reconstruct": recon,
        "bytearray 2^40": b"cbuiltins\nbytearray\n\x8a\x06\x00\x00\x00\x00\x00\x01\x85R",
        # numpy.ndarray((100000, 100000)) called: 80 GB
        "ndarray call 1e5 x 1e5": b"cnumpy\nndarray\nJ\xa0\x86\x01\x00J\xa0\x86\x01\x00\x86\x85R",
    }


# ------------------------------------------------------------------------- mutations


def byte_mutations(data: bytes, rng) -> list[tuple[str, bytes]]:
    out = [("empty file", b"")]
    for i in range(12):
        out.append((f"truncated {i}", data[: int(len(data) * rng.random())]))
    for i in range(24):
        b = bytearray(data)
        for _ in range(1 + i % 3):
            at = int(rng.integers(len(b)))
            b[at] ^= 1 << int(rng.integers(8))
        out.append((f"bit flip {i}", bytes(b)))
    for i in range(8):
        b = bytearray(data)
        at = int(rng.integers(len(b)))
        b[at : at + 16] = bytes(16)
        out.append((f"zeroed run {i}", bytes(b)))
    for i in range(4):
        out.append((f"random bytes {i}", rng.bytes(int(rng.integers(1, 4096)))))
    return out


def value_mutations(d: dict, rng) -> list[tuple[str, dict]]:
    """Each key dropped, NaN, Inf, huge, wrong dtype, wrong shape (leaves of nested dicts)."""
    out = []
    for key, value in d.items():
        if isinstance(value, dict):
            out += [
                (f"{key}.{label}", {**d, key: sub}) for label, sub in value_mutations(value, rng)
            ]
            continue
        out.append((f"{key} dropped", {k: v for k, v in d.items() if k != key}))
        if not isinstance(value, np.ndarray) or value.dtype.kind not in "biuf":
            out.append((f"{key} as array", {**d, key: np.zeros(3)}))
            continue
        a = value.astype(np.float64) if value.dtype.kind == "f" else value
        for label, changed in (
            ("NaN", np.where(np.ones_like(a, bool), np.nan, a) if a.size else a),
            ("Inf", np.full_like(a, np.inf, dtype=np.float64)),
            ("1e30", np.full_like(a, 1e30, dtype=np.float64)),
            ("1e6", np.full_like(a, 1e6, dtype=np.float64)),
            ("-1", np.full_like(a, -1)),
            ("complex", a.astype(np.complex128) + 1j),
            ("text", np.array(["x"] * max(a.size, 1))),
            ("fractional", a.astype(np.float64) + 0.5),
            ("empty", a.reshape(-1)[:0]),
            ("extra axis", a[None, None]),
            ("flattened", a.reshape(-1)),
            ("bool", a.astype(bool)),
        ):
            out.append((f"{key} {label}", {**d, key: changed}))
    return out


def _patch_zip(data: bytes, what: str) -> bytes:
    """One zip member given deflate64 (method 9), the encryption flag, a version needed to
    extract past what Python's zipfile reads (12.8: zipfile raises NotImplementedError), or
    a huge size."""
    b = bytearray(data)
    local, central = b.find(b"PK\x03\x04"), b.find(b"PK\x01\x02")
    if what == "deflate64":
        struct.pack_into("<H", b, local + 8, 9)
        struct.pack_into("<H", b, central + 10, 9)
    elif what == "encrypted":
        for at, off in ((local, 6), (central, 8)):
            struct.pack_into("<H", b, at + off, struct.unpack_from("<H", b, at + off)[0] | 1)
    elif what == "future version":
        struct.pack_into("<H", b, central + 6, 128)
    else:  # a member claiming 4 GiB uncompressed
        struct.pack_into("<I", b, local + 22, 0xFFFFFFF0)
        struct.pack_into("<I", b, central + 24, 0xFFFFFFF0)
    return bytes(b)


def zip_mutations(data: bytes) -> list[tuple[str, bytes]]:
    import io

    kinds = ("deflate64", "encrypted", "future version", "size bomb")
    out = [(f"zip {w}", _patch_zip(data, w)) for w in kinds]
    buf = io.BytesIO(data)
    with zipfile.ZipFile(buf) as z:
        first = z.infolist()[0].filename
        last = z.infolist()[-1].filename
    for name in {first, last}:
        dup = io.BytesIO(data)
        with warnings.catch_warnings(), zipfile.ZipFile(dup, "a") as z:
            warnings.simplefilter("ignore")
            z.writestr(name, b"\x93NUMPY" + bytes(100))
        out.append((f"duplicate member {name}", dup.getvalue()))
    out.append(("deflate bomb (96 MiB of zeros in the first member)", _deflate_bomb(data)))
    return out


def _deflate_bomb(data: bytes) -> bytes:
    """The archive with its first member replaced by a real deflated npy of 96 MiB of zeros:
    its sizes are all true, only the ratio gives it away (zip_check.INFLATE_RATIO)."""
    import io

    zeros = io.BytesIO()
    np.save(zeros, np.zeros(96 << 17))  # 96 MiB of float64
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(out, "w") as dst:
        for i, info in enumerate(src.infolist()):
            payload = zeros.getvalue() if i == 0 else src.read(info)
            dst.writestr(info.filename, payload, compress_type=zipfile.ZIP_DEFLATED)
    return out.getvalue()


def npy_header_bomb(shape, descr="<f8") -> bytes:
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buf, {"descr": descr, "fortran_order": False, "shape": shape}
    )
    return buf.getvalue() + bytes(64)


def npz_mutations(arrays: dict, rng) -> list[tuple[str, bytes]]:
    import io

    out = [(label, npz_bytes(a)) for label, a in value_mutations(arrays, rng)]
    out += zip_mutations(npz_bytes(arrays))
    for key in list(arrays)[:3]:
        for shape in ((30_000_000_000,), (1 << 20, 1 << 20, 3)):
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w") as z:
                for k, v in arrays.items():
                    member = io.BytesIO()
                    np.save(member, v)
                    z.writestr(
                        f"{k}.npy", npy_header_bomb(shape) if k == key else member.getvalue()
                    )
            out.append((f"{key} header claims {shape}", buf.getvalue()))
    garbled = io.BytesIO()  # a header literal numpy's tokenizer fails on (TokenError)
    with zipfile.ZipFile(garbled, "w") as z:
        for i, (k, v) in enumerate(arrays.items()):
            member = io.BytesIO()
            np.save(member, v)
            data = member.getvalue()
            if i == 0:
                end = data.index(b"}")
                data = data[:10] + b"{'descr': '''".ljust(end - 9) + data[end + 1 :]
            z.writestr(f"{k}.npy", data)
    out.append(("npy header with an unterminated string", garbled.getvalue()))
    obj = io.BytesIO()
    with zipfile.ZipFile(obj, "w") as z:
        for k, v in arrays.items():
            member = io.BytesIO()
            np.save(member, np.array([v, None], dtype=object) if k == next(iter(arrays)) else v)
            z.writestr(f"{k}.npy", member.getvalue())
    out.append(("object-dtype member (pickle inside)", obj.getvalue()))
    return out + npz_size_bombs(arrays)


# ------------------------------------------------------------------------- size bombs

BOMB_BYTES = 3 << 30  # what each crafted file below declares: 3 GiB from about 3 MB


def _zeros_crc(n_mib: int, crc: int = 0) -> int:
    zero = bytes(1 << 20)
    for _ in range(n_mib):
        crc = zlib.crc32(zero, crc)
    return crc


@functools.cache
def _deflated(head: bytes, n_mib: int) -> tuple[bytes, int]:
    """A raw deflate stream of `head` then `n_mib` MiB of zeros, and its CRC-32: each MiB
    is deflated once after a full flush (which resets the window), so the stream is that
    MiB's 1 kB repeated, built in milliseconds."""
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    first = c.compress(head) + c.flush(zlib.Z_FULL_FLUSH)
    mib = c.compress(bytes(1 << 20)) + c.flush(zlib.Z_FULL_FLUSH)
    return first + mib * n_mib + c.flush(), _zeros_crc(n_mib, zlib.crc32(head))


def raw_zip(members: list[tuple[str, int, bytes, int, int]]) -> bytes:
    """A zip archive written field by field from (name, method, payload as stored, CRC-32,
    declared uncompressed size): the directory says whatever it is given."""
    body, central = b"", b""
    for name, method, payload, crc, size in members:
        fixed = struct.pack("<HHHHHIII", 20, 0, method, 0, 0x21, crc, len(payload), size)
        head = fixed + struct.pack("<HH", len(name), 0) + name.encode()
        central += b"PK\x01\x02" + struct.pack("<H", 20) + head[: -len(name)]
        central += struct.pack("<HHHII", 0, 0, 0, 0, len(body)) + name.encode()
        body += b"PK\x03\x04" + head + payload
    end = struct.pack("<4sHHHHIIH", b"PK\x05\x06", 0, 0, len(members), len(members),
                      len(central), len(body), 0)  # fmt: skip
    return body + central + end


def _members(data: bytes) -> list[tuple[str, int, bytes, int, int]]:
    import io

    with zipfile.ZipFile(io.BytesIO(data)) as z:
        return [(i.filename, zipfile.ZIP_STORED, z.read(i), i.CRC, i.file_size)
                for i in z.infolist()]  # fmt: skip


def torch_size_bombs(data: bytes) -> list[tuple[str, bytes]]:
    """A torch.save archive (`data`) whose first storage (`data/0`, the first tensor's)
    declares 3 GiB: in its pickle's persistent id, in its member, or both."""
    import re

    members = _members(data)
    at = next(i for i, m in enumerate(members) if m[0].endswith("/data/0"))
    name, _, payload, _, size = members[at]
    stream, crc = _deflated(b"", BOMB_BYTES >> 20)
    pkl = next(i for i, m in enumerate(members) if m[0].endswith("/data.pkl"))
    numel = re.compile(rb"(X\x03\x00\x00\x00cpuq.)(K.|M..|J....)t", re.DOTALL)

    def archive(storage=None, elements=None):
        out = list(members)
        if storage is not None:
            out[at] = storage
        if elements is not None:
            p = out[pkl]
            new = numel.sub(lambda m: m[1] + b"J" + struct.pack("<i", elements) + b"t", p[2], 1)
            out[pkl] = (p[0], p[1], new, zlib.crc32(new), len(new))
        return raw_zip(out)

    deflated = (name, zipfile.ZIP_DEFLATED, stream, crc, BOMB_BYTES)
    # the directory declares the storage's true size, its bytes inflate to 3 GiB
    lying = (name, zipfile.ZIP_DEFLATED, stream, zlib.crc32(bytes(size)), size)
    # the directory declares as many bytes as the stream has compressed (within deflate's
    # bound), its bytes inflate to 3 GiB: read up to the declared size, a tensor of zeros
    fits = (name, zipfile.ZIP_DEFLATED, stream, zlib.crc32(bytes(len(stream))), len(stream))
    # a stored member the directory says is 3 GiB, holding what deflate's ratio allows
    big = bytes(BOMB_BYTES // 1000)
    stored = (name, zipfile.ZIP_STORED, big, zlib.crc32(big), BOMB_BYTES)
    return [
        ("storage of 3 GiB, deflated (pickle and directory agree)",
         archive(deflated, BOMB_BYTES // 4)),
        ("storage member inflating to 3 GiB, directory says its true size",
         archive(lying)),
        ("storage member inflating to 3 GiB, directory says 3 MB", archive(fits)),
        ("pickle declares a storage of 3 GiB over a small member",
         archive(elements=BOMB_BYTES // 4)),
        ("pickle declares 3 GiB, member inflates to 3 GiB, directory says its true size",
         archive(lying, BOMB_BYTES // 4)),
        ("storage stored, its directory entry claims 3 GiB", archive(stored, BOMB_BYTES // 4)),
    ]  # fmt: skip


def npz_size_bombs(arrays: dict) -> list[tuple[str, bytes]]:
    """The first member of an npz made to declare 3 GiB: an npy header whose shape says so,
    with the member deflated to 3 MB, stored, or with a directory that understates it."""
    key = next(iter(arrays))
    members = _members(npz_bytes(arrays))
    name, _, payload, _, size = members[0]
    header = npy_header_bomb((BOMB_BYTES // 8,))[:-64]
    stream, crc = _deflated(header, BOMB_BYTES >> 20)
    held = header + bytes(BOMB_BYTES // 1000)
    cases = {
        "deflated to 3 MB (header and directory agree)":
            (name, zipfile.ZIP_DEFLATED, stream, crc, len(header) + BOMB_BYTES),
        "inflating to 3 GiB, directory says the seed's size":
            (name, zipfile.ZIP_DEFLATED, stream, zlib.crc32(payload), size),
        "stored, directory claims 3 GiB for 3 MB":
            (name, zipfile.ZIP_STORED, held, zlib.crc32(held), len(header) + BOMB_BYTES),
        "header alone (64 bytes held)":
            (name, zipfile.ZIP_STORED, header + bytes(64), zlib.crc32(header + bytes(64)),
             len(header) + 64),
    }  # fmt: skip
    return [
        (f"{key} header claims 3 GiB, {label}", raw_zip([member, *members[1:]]))
        for label, member in cases.items()
    ]


def pickle_mutations(d: dict, rng, marker: Path, splice) -> list[tuple[str, bytes]]:
    """`splice(dict_with_sentinel) -> bytes with the fragment in place of the sentinel`."""
    key = next(iter(d))
    out = []
    for label, fragment in {**bomb_fragments(), **code_fragments(marker)}.items():
        out.append((label, splice({**d, key: SENTINEL}, fragment)))
    return out


def splice_pickle(d, fragment) -> bytes:
    return fast_pickle(d).replace(_SENTINEL_OP, fragment)


def splice_torch(d, fragment) -> bytes:
    import io

    data = torch_bytes(d)
    src = zipfile.ZipFile(io.BytesIO(data))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        for info in src.infolist():
            content = src.read(info)
            if info.filename.endswith("/data.pkl"):
                content = content.replace(_SENTINEL_OP, fragment)
            z.writestr(info.filename, content)
    return out.getvalue()


def json_mutations(d: dict, rng) -> list[tuple[str, bytes]]:
    out = []

    def walk(node, path):
        for key, value in list(node.items()) if isinstance(node, dict) else []:
            for label, new in (
                ("dropped", None), ("NaN", math.nan), ("Infinity", math.inf), ("1e300", 1e300),
                ("-1", -1), ("0", 0), ("text", "x"), ("list", [1, 2]), ("true", True),
                ("null", "null"), ("2^62", 1 << 62), ("fraction", 2.5),
            ):  # fmt: skip
                copy = json.loads(json.dumps(d))
                target = copy
                for p in path:
                    target = target[p]
                if new is None:
                    del target[key]
                else:
                    target[key] = None if new == "null" else new
                out.append((f"{'.'.join(map(str, path + [key]))} {label}", json.dumps(copy)))
            if isinstance(value, dict):
                walk(value, path + [key])

    walk(d, [])
    out.append(("deep nesting", "[" * 100_000 + "]" * 100_000))
    out.append(("top-level list", "[1, 2]"))
    out.append(("unknown key", json.dumps({**d, "zzz": 1})))
    return [(label, text.encode()) for label, text in out]


def ply_mutations(data: bytes, rng) -> list[tuple[str, bytes]]:
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header, body = data[:end].decode(), data[end:]
    out = []
    for label, old, new in (
        ("count huge", "element vertex 20", "element vertex 99999999999"),
        ("count negative", "element vertex 20", "element vertex -5"),
        ("count text", "element vertex 20", "element vertex many"),
        ("count missing", "element vertex 20", "element vertex"),
        ("ascii format", "binary_little_endian", "ascii"),
        ("big endian", "binary_little_endian", "binary_big_endian"),
        ("list property", "property float x", "property list uchar float x"),
        ("unknown type", "property float y", "property quad y"),
        ("repeated property", "property float z", "property float x"),
        ("no rot_0", "property float rot_0", "property float rot_9"),
        ("no end_header", "end_header", "end_headr"),
        ("double type", "property float opacity", "property double opacity"),
        ("f_rest odd", "property float f_rest_44", "property float g_rest_44"),
    ):
        out.append((f"header {label}", header.replace(old, new).encode() + body))
    floats = np.frombuffer(body, F32).copy()
    for label, value in (("NaN", np.nan), ("Inf", np.inf), ("1e30", 1e30), ("-1e30", -1e30)):
        for i in range(5):
            f = floats.copy()
            f[int(rng.integers(len(f)))] = value
            out.append((f"body {label} {i}", header.encode() + f.tobytes()))
    q = floats.reshape(20, -1).copy()
    q[3, -4:] = 0
    out.append(("zero quaternion", header.encode() + q.tobytes()))
    return out


# ------------------------------------------------------------------------- more cases
# Cases added for issue 33's aim of at least 150 files per reader. Each draws from its own
# generator (SEED + an offset), so the cases above keep the files they always had.


def more_byte_mutations(data: bytes, seed: int) -> list[tuple[str, bytes]]:
    """Byte damage byte_mutations does not make: truncation at fixed points (the last byte,
    the first 8 bytes, halfway), bytes deleted or inserted (every offset after them shifts),
    runs of 0xff, and single bit flips from a second generator."""
    rng = np.random.default_rng(SEED + seed)
    out = [
        ("truncated by the last byte", data[:-1]),
        ("truncated to 8 bytes", data[:8]),
        ("truncated halfway", data[: len(data) // 2]),
    ]
    for i in range(3):
        at = int(rng.integers(len(data)))
        out.append((f"byte {i} deleted", data[:at] + data[at + 1 :]))
    for i in range(2):
        at = int(rng.integers(len(data)))
        out.append((f"byte {i} inserted", data[:at] + bytes([int(rng.integers(256))]) + data[at:]))
    for i in range(2):
        b = bytearray(data)
        at = int(rng.integers(len(b)))
        b[at : at + 32] = b"\xff" * len(b[at : at + 32])
        out.append((f"0xff run {i}", bytes(b)))
    for i in range(3):
        b = bytearray(data)
        at = int(rng.integers(len(b)))
        b[at] ^= 1 << int(rng.integers(8))
        out.append((f"single bit flip {i}", bytes(b)))
    return out


def _cache_more_cases(arrays: dict) -> list[tuple[str, bytes]]:
    """Cache frames whose checksum matches what they hold, each with one key missing or of a
    type, shape or value read_frame refuses: only its own checks can catch them."""
    from archhead_addon.io.checksum import KEY, with_checksum

    plain = {k: v for k, v in arrays.items() if k != KEY}
    n = len(plain["means"])
    nan, inf = plain["opacity_logits"].copy(), plain["log_scales"].copy()
    nan[3], inf[5, 1] = np.nan, np.inf
    cases = [(f"{k} dropped", {kk: v for kk, v in plain.items() if kk != k}) for k in plain]
    cases += [
        ("means float64", {**plain, "means": plain["means"].astype(np.float64)}),
        ("sh of 5 bands", {**plain, "sh": np.zeros((n, 5, 3), F32)}),
        ("quats one row short", {**plain, "quats": plain["quats"][:-1]}),
        ("opacity_logits NaN", {**plain, "opacity_logits": nan}),
        ("log_scales Inf", {**plain, "log_scales": inf}),
        ("resolution float", {**plain, "resolution": np.float64(64)}),
        ("resolution shape (1,)", {**plain, "resolution": np.array([64])}),
    ]
    return [(f"{label} with a valid checksum", npz_bytes(with_checksum(a))) for label, a in cases]


def _clip_cases(clip: dict) -> list[tuple[str, dict]]:
    """Driving clips whose parts disagree or hold what no clip has (both containers)."""
    exp, jaw = clip["exp"], clip["jaw"]
    return [
        ("jaw one frame short", {**clip, "jaw": jaw[:-1]}),
        ("jaw (T, 4)", {**clip, "jaw": np.zeros((5, 4), F32)}),
        ("no frames", {**clip, "exp": exp[:0], "jaw": jaw[:0]}),
        ("exp one-dimensional", {**clip, "exp": exp[0]}),
        ("fps 0", {**clip, "fps": 0.0}),
        ("fps negative", {**clip, "fps": -30.0}),
        ("fps 1e9", {**clip, "fps": 1e9}),
        ("fps of two values", {**clip, "fps": np.array([30.0, 25.0])}),
        ("exp float16", {**clip, "exp": exp.astype(np.float16)}),
        ("exp big-endian", {**clip, "exp": exp.astype(">f4")}),
        ("exp Fortran order", {**clip, "exp": np.asfortranarray(exp)}),
        ("exp renamed expr", {**{k: v for k, v in clip.items() if k != "exp"}, "expr": exp}),
        ("unknown extra key", {**clip, "zzz": np.zeros(2)}),
    ]


def _clip_npz_cases(clip: dict) -> list[tuple[str, bytes]]:
    """Archives numpy writes differently or not at all: members without the .npy suffix or
    in a folder, no members, a bare .npy, a zip of text, npy format 2.0 and 3.0 headers."""
    import io

    def archive(members):
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            for name, data in members:
                z.writestr(name, data)
        return buf.getvalue()

    def npy(v, version=None):
        buf = io.BytesIO()
        np.lib.format.write_array(buf, np.asanyarray(v), version=version)
        return buf.getvalue()

    out = [(label, npz_bytes({**c, "fps": np.asarray(c["fps"], np.float64)}))
           for label, c in _clip_cases(clip)]  # fmt: skip
    out += [
        ("exp member without .npy", archive([(("exp" if k == "exp" else f"{k}.npy"), npy(v))
                                              for k, v in clip.items()])),
        ("members in a folder", archive([(f"clip/{k}.npy", npy(v)) for k, v in clip.items()])),
        ("no members", archive([])),
        ("a bare .npy of exp", npy(clip["exp"])),
        ("exp member of text", archive([(f"{k}.npy", b"exp,jaw\n1,2\n" if k == "exp" else npy(v))
                                        for k, v in clip.items()])),
        ("npy format 2.0", archive([(f"{k}.npy", npy(v, (2, 0))) for k, v in clip.items()])),
        ("npy format 3.0", archive([(f"{k}.npy", npy(v, (3, 0))) for k, v in clip.items()])),
    ]  # fmt: skip
    return out


def _clip_pickle_cases(clip: dict) -> list[tuple[str, bytes]]:
    """Pickled clips of another shape: not a dict, Python lists (ragged too), the clip
    nested one level down, other protocols (4 with frames, 0 as text), two pickles in one."""
    exp = clip["exp"]
    ragged = [row.tolist()[: 5 - i % 2] for i, row in enumerate(exp)]  # rows of 5 and 4
    objects = [
        ("a list, not a dict", [clip["exp"], clip["jaw"], clip["fps"]]),
        ("a tuple, not a dict", (clip["exp"], clip["jaw"], clip["fps"])),
        ("None", None),
        ("a string", "exp jaw fps"),
        ("clip nested under a key", {"clip": clip}),
        ("exp as nested lists", {**clip, "exp": exp.tolist()}),
        ("exp as ragged lists", {**clip, "exp": ragged}),
        ("fps as text", {**clip, "fps": "30"}),
        ("fps as int", {**clip, "fps": 30}),
    ]
    out = [(label, fast_pickle(obj)) for label, obj in objects]
    out += [(label, fast_pickle(c)) for label, c in _clip_cases(clip)]
    proto4 = pickle.dumps(clip, protocol=4)
    out += [
        ("protocol 4 (framed)", proto4),
        ("protocol 4 truncated inside a frame", proto4[: len(proto4) // 3]),
        ("protocol 0 (text)", pickle.dumps({k: np.asarray(v).tolist() for k, v in clip.items()},
                                           protocol=0)),
        ("two pickles in one file", fast_pickle(clip) + fast_pickle({"exp": None})),
    ]  # fmt: skip
    return out


def ply_more_mutations(data: bytes) -> list[tuple[str, bytes]]:
    """Header variants: vertex counts off by one or more than the body holds, properties
    missing or of other types (the body then misread), ascii or big-endian bodies under
    their own or the other format line, CRLF, comments, other elements."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header, body = data[:end].decode(), data[end:]
    lines = header.splitlines()

    def without(name):
        return "\n".join(x for x in lines if x != f"property float {name}") + "\n"

    out = []
    for label, old, new in (
        ("count one fewer", "element vertex 20", "element vertex 19"),
        ("count one more", "element vertex 20", "element vertex 21"),
        ("count doubled", "element vertex 20", "element vertex 40"),
        ("count 0", "element vertex 20", "element vertex 0"),
        ("count zero-padded", "element vertex 20", "element vertex 020"),
        ("count float", "element vertex 20", "element vertex 20.0"),
        ("count exponent", "element vertex 20", "element vertex 2e1"),
        ("count with a sign", "element vertex 20", "element vertex +20"),
        ("count with an extra token", "element vertex 20", "element vertex 20 3"),
        ("x uchar", "property float x\n", "property uchar x\n"),
        ("x int", "property float x\n", "property int x\n"),
        ("opacity short", "property float opacity", "property short opacity"),
        ("rot_0 double", "property float rot_0", "property double rot_0"),
        ("scale_0 uint", "property float scale_0", "property uint scale_0"),
        ("x float32", "property float x\n", "property float32 x\n"),
        ("property with an extra token", "property float y", "property float y z2"),
        ("property without a name", "property float z\n", "property float\n"),
        ("format version 2.0", "binary_little_endian 1.0", "binary_little_endian 2.0"),
        ("format line dropped", "format binary_little_endian 1.0\n", ""),
        ("magic PLY", "ply\n", "PLY\n"),
        ("face element first", "element vertex 20", "element face 3\nelement vertex 20"),
        ("CRLF line ends", "\n", "\r\n"),
        ("comments", "element vertex 20", "comment made by hand\nelement vertex 20\nobj_info x"),
    ):
        out.append((f"header {label}", header.replace(old, new).encode() + body))
    for name in ("x", "scale_2", "opacity", "f_dc_1", "rot_3", "f_rest_44"):
        out.append((f"header without property {name}", without(name).encode() + body))
    table = np.frombuffer(body, F32).reshape(20, -1)
    text = "\n".join(" ".join(f"{v:.6g}" for v in row) for row in table) + "\n"
    ascii_header = header.replace("binary_little_endian", "ascii")
    out += [
        ("ascii body under an ascii header", (ascii_header + text).encode()),
        ("ascii body under a binary header", (header + text).encode()),
        ("big-endian body under a big-endian header",
         header.replace("little", "big").encode() + table.astype(">f4").tobytes()),
        ("big-endian body under a little-endian header",
         header.encode() + table.astype(">f4").tobytes()),
        ("face element after the vertices",
         header.replace("end_header", "element face 1\nproperty list uchar int vertex_indices\n"
                        "end_header").encode() + body + b"\x03" + bytes(12)),
        ("trailing bytes after the body", header.encode() + body + bytes(100)),
        ("header alone", header.encode()),
        ("header of 70,000 comment lines",
         header.replace("ply\n", "ply\n" + "comment x\n" * 70_000).encode() + body),
        ("quaternions of 1e-30", header.encode() + _scaled_quats(table, 1e-30)),
        ("all-zero vertex", header.encode() + _zero_row(table, 7)),
    ]  # fmt: skip
    return out


def _scaled_quats(table: np.ndarray, factor: float) -> bytes:
    t = table.copy()
    t[:, -4:] *= factor
    return t.astype(F32).tobytes()


def _zero_row(table: np.ndarray, row: int) -> bytes:
    t = table.copy()
    t[row] = 0
    return t.tobytes()


def _vhap_more_cases(transforms: dict) -> list[tuple[str, str, bytes]]:
    """transforms.json variants: frames of the wrong kind, transform matrices of the wrong
    shape or content, flame_param paths that lead nowhere or out of the folder, cameras and
    timesteps that do not line up, per-frame intrinsics that disagree, other encodings."""
    import copy

    def changed(change):
        t = copy.deepcopy(transforms)
        change(t)
        return json.dumps(t).encode()

    def frame(key, value, i=1):
        return changed(lambda t: t["frames"][i].update({key: value}))

    eye = np.eye(4).tolist()
    good = json.dumps(transforms)
    cases = [
        ("frames empty", changed(lambda t: t.update(frames=[]))),
        ("frames an object", changed(lambda t: t.update(frames={"0": t["frames"][0]}))),
        ("frames of numbers", changed(lambda t: t.update(frames=[1, 2]))),
        ("top-level list", json.dumps(transforms["frames"]).encode()),
        ("transform_matrix dropped", changed(lambda t: t["frames"][1].pop("transform_matrix"))),
        ("transform_matrix 3x4", frame("transform_matrix", eye[:3])),
        ("transform_matrix 3x3", frame("transform_matrix", [r[:3] for r in eye[:3]])),
        ("transform_matrix ragged", frame("transform_matrix", [*eye[:3], [0, 0, 1]])),
        ("transform_matrix of text", frame("transform_matrix", [["1"] * 4] * 4)),
        ("transform_matrix with NaN", frame("transform_matrix", [[math.nan] * 4, *eye[1:]])),
        ("transform_matrix last row not 0 0 0 1",
         frame("transform_matrix", [*eye[:3], [1, 0, 0, 1]])),
        ("transform_matrix scaled by 1e6", frame("transform_matrix", (np.eye(4) * 1e6).tolist())),
        ("flame_param_path ../", frame("flame_param_path", "../00001.npz")),
        ("flame_param_path absolute", frame("flame_param_path", "/etc/hostname")),
        ("flame_param_path empty", frame("flame_param_path", "")),
        ("flame_param_path a folder", frame("flame_param_path", "flame_param")),
        ("flame_param_path missing file", frame("flame_param_path", "flame_param/00009.npz")),
        ("flame_param_path NUL byte", frame("flame_param_path", "flame_param/0\x00.npz")),
        ("flame_param_path 5000 characters", frame("flame_param_path", "a/" * 2500)),
        ("flame_param_path a number", frame("flame_param_path", 1)),
        ("both frames one flame_param", frame("flame_param_path", "flame_param/00000.npz")),
        ("timestep_index repeated", frame("timestep_index", 0)),
        ("timestep_index dropped", changed(lambda t: t["frames"][1].pop("timestep_index"))),
        ("timestep_index 2^62", frame("timestep_index", 1 << 62)),
        ("camera_index 1 for one frame", frame("camera_index", 1)),
        ("camera_index 1.5", frame("camera_index", 1.5)),
        ("per-frame w differs", frame("w", 512)),
        ("per-frame fl_x", frame("fl_x", 600.0)),
        ("per-frame fl_y 0", frame("fl_y", 0)),
        ("h 0", changed(lambda t: t.update(h=0))),
        ("cx text", changed(lambda t: t.update(cx="128"))),
        ("intrinsics dropped", changed(lambda t: [t.pop(k) for k in ("fl_x", "fl_y")])),
        ("UTF-8 byte order mark", b"\xef\xbb\xbf" + good.encode()),
        ("UTF-16", good.encode("utf-16")),
        ("trailing garbage", good.encode() + b" }"),
        ("two objects", (good + good).encode()),
    ]  # fmt: skip
    return [(label, "transforms.json", data) for label, data in cases]


# ------------------------------------------------------------------------- held-out kinds
# Kinds of file issue 33's held-out corpus made and the cases above did not: legal
# containers numpy, zipfile and torch write otherwise (npy 2.0 headers, Fortran order,
# big-endian arrays, deflated members, data descriptors, zip64 records, pickle protocol 5,
# OrderedDicts, scipy.sparse matrices), and values each reader let through: integers beyond
# float's range in JSON (an OverflowError), a PLY count of 5000 digits, SH of no degree,
# skewed or mirrored cameras, Adam settings of a training state, a sparse matrix whose indptr
# claims 2^40 values. Labels start "held-out error:" (to be refused) or "held-out same:" (to
# be read as the seed is); tests/test_fuzz_inputs.py checks each.


def _zip_members(members, method=zipfile.ZIP_STORED, stream=False, zip64=False) -> bytes:
    """A zip of (name, bytes); `stream`: written unseekable, so every member has a data
    descriptor (flag bit 3), as streaming writers make them."""
    import io

    buf = io.BytesIO()
    target = buf
    if stream:

        class Unseekable(io.RawIOBase):
            def writable(self):
                return True

            def write(self, b):
                return buf.write(b)

        target = Unseekable()
    with zipfile.ZipFile(target, "w", method) as z:
        for name, data in members:
            info = zipfile.ZipInfo(name, (2020, 1, 1, 0, 0, 0))
            info.compress_type = method
            with z.open(info, "w", force_zip64=zip64) as f:
                f.write(data)
    return buf.getvalue()


def _npy(value, version=None, fortran=False, big=False) -> bytes:
    import io

    a = np.asanyarray(value)
    if big and a.dtype.kind in "iuf" and a.dtype.itemsize > 1:
        a = a.astype(a.dtype.newbyteorder(">"))
    if fortran and a.ndim >= 2:
        a = np.asfortranarray(a)
    buf = io.BytesIO()
    np.lib.format.write_array(buf, a, version=version, allow_pickle=False)
    return buf.getvalue()


def _npy_header(header: str) -> bytes:
    """A version 1.0 npy member of this header text and no data."""
    text = header.encode("latin1")
    text += b" " * (63 - (10 + len(text)) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text


def heldout_npz_cases(arrays: dict, checksummed: bool = False) -> list[tuple[str, bytes]]:
    """npz variants: legal layouts (read as the seed) and members no array has. A file with
    a checksum keeps it valid only where the bytes hashed stay the same (not big-endian)."""
    members = [(f"{k}.npy", _npy(v)) for k, v in arrays.items()]
    first = next(k for k, v in arrays.items() if v.dtype.kind in "iuf" and v.ndim >= 1)

    def with_first(member):
        return _zip_members([(n, member if n == f"{first}.npy" else d) for n, d in members])

    def layout(**kw):
        return _zip_members([(f"{k}.npy", _npy(v, **kw)) for k, v in arrays.items()])

    same = [
        ("npy 2.0 headers", layout(version=(2, 0))),
        ("Fortran-order arrays", layout(fortran=True)),
        ("deflated members (savez_compressed)", _zip_members(members, zipfile.ZIP_DEFLATED)),
        ("data descriptors (a streamed zip)", _zip_members(members, stream=True)),
        ("zip64 records", _zip_members(members, zip64=True)),
    ]
    if not checksummed:
        same.append(("big-endian arrays", layout(big=True)))
    error = [
        (f"{first} member a whole npz (nested zip)", with_first(_zip_members(members))),
        (f"{first} 0-d", with_first(_npy(np.float64(1.0)))),
        (f"{first} header shape (2^40, 0)", with_first(_npy_header(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (1099511627776, 0), }"))),
        (f"{first} header with an extra key", with_first(_npy_header(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (0,), 'x': 1, }"))),
        (f"{first} datetime64", with_first(_npy(np.zeros(2, "<M8[s]")))),
    ]  # fmt: skip
    return [(f"held-out same: {label}", data) for label, data in same] + [
        (f"held-out error: {label}", data) for label, data in error
    ]


def heldout_camera_cases(arrays: dict) -> list[tuple[str, bytes]]:
    """A skewed K (Blender's camera has no skew) and a mirrored w2c (determinant -1)."""
    out = []
    if "K" in arrays:
        K = arrays["K"].copy()
        K[..., 0, 1] = 0.5
        out.append(("held-out error: K skew 0.5 px", npz_bytes({**arrays, "K": K})))
    if "w2c" in arrays:
        w2c = arrays["w2c"].copy()
        w2c[:, 0, 0] = -1.0
        out.append(("held-out error: w2c a reflection", npz_bytes({**arrays, "w2c": w2c})))
    return out


def heldout_metrical_cases(frame: dict) -> list[tuple[str, bytes]]:
    mirrored = {**frame["opencv"], "R": np.diag([1, 1, -1]).astype(F32)[None]}
    K = frame["opencv"]["K"].copy()
    K[0, 0, 1] = 1e6
    return [
        ("held-out error: opencv.R a reflection", torch_bytes({**frame, "opencv": mirrored})),
        ("held-out error: opencv.K skew 1e6",
         torch_bytes({**frame, "opencv": {**frame["opencv"], "K": K}})),
        ("held-out same: pickle protocol 5", _torch_protocol(frame, 5)),
    ]  # fmt: skip


def _torch_protocol(obj, protocol: int) -> bytes:
    import io

    import torch

    def tensors(v):
        if isinstance(v, np.ndarray) and v.dtype.kind in "biufc":
            return torch.from_numpy(v)
        return {k: tensors(x) for k, x in v.items()} if isinstance(v, dict) else v

    buf = io.BytesIO()
    torch.save(tensors(obj), buf, pickle_protocol=protocol)
    return buf.getvalue()


def _csc_pickle(flame: dict, **override) -> bytes:
    """The FLAME dict with J_regressor as a scipy.sparse csc_matrix, pickled as scipy does
    (NEWOBJ, then its __dict__ as state), without scipy."""
    J = flame["J_regressor"]
    indptr, indices, data = [0], [], []
    for column in J.T:
        nonzero = np.nonzero(column)[0]
        indices += nonzero.tolist()
        data += column[nonzero].tolist()
        indptr.append(len(indices))
    state = {"indices": np.array(indices, np.int32), "indptr": np.array(indptr, np.int32),
             "data": np.array(data), "_shape": J.shape, "maxprint": 50, **override}  # fmt: skip
    csc = b"cscipy.sparse._csc\ncsc_matrix\n)\x81" + fast_pickle(state)[2:-1] + b"b"
    return splice_pickle({**flame, "J_regressor": SENTINEL}, csc)


def heldout_flame_pickle_cases(flame: dict) -> list[tuple[str, bytes]]:
    n = flame["J_regressor"].shape[1]
    return [
        ("held-out same: J_regressor a csc_matrix (FLAME 2023)", _csc_pickle(flame)),
        ("held-out same: an OrderedDict", pickle.dumps(collections.OrderedDict(flame), protocol=2)),
        ("held-out same: protocol 5", pickle.dumps(flame, protocol=5)),
        ("held-out error: csc indptr claiming 2^40 values",
         _csc_pickle(flame, indptr=np.array([0] + [1 << 40] * n, np.int64))),
        ("held-out error: csc indices fractional",
         _csc_pickle(flame, indices=np.zeros(1, np.float64) + 0.5)),
    ]  # fmt: skip


def heldout_json_cases(config: dict) -> list[tuple[str, bytes]]:
    """Integers beyond float's range (JSON has no limit: Python reads 10^400 exactly)."""
    huge = "1" + "0" * 400
    out = []
    for path in (("resolution",), ("lr", "features"), ("avatar", "tau"), ("threads",),
                 ("loss", "parts")):  # fmt: skip
        d = json.loads(json.dumps(config))
        target = d
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = "__HUGE__"
        text = json.dumps(d).replace('"__HUGE__"', huge)
        out.append((f"held-out error: {'.'.join(path)} 10^400", text.encode()))
    return out


def heldout_state_cases(state: dict) -> list[tuple[str, bytes]]:
    """Training states, checksum made anew, whose plain values are off: Adam's settings
    (torch's load_state_dict resumes with the file's), huge integers, booleans."""
    import copy

    from archhead_addon.io.checksum import KEY, tree_checksum

    def case(change):
        s = copy.deepcopy(state)
        change(s)
        s = {k: v for k, v in s.items() if k != KEY}
        return torch_bytes({**s, KEY: tree_checksum(s)})

    def group(**kw):
        return lambda s: s["optimizer"]["param_groups"][0].update(kw)

    huge = 10**400
    tau = json.loads(state["avatar_config"])
    tau["tau"] = "__HUGE__"
    avatar = json.dumps(tau).replace('"__HUGE__"', str(huge))
    cases = {
        "elapsed 10^400": lambda s: s.update(elapsed=huge),
        "elapsed true": lambda s: s.update(elapsed=True),
        "version true": lambda s: s.update(version=True),
        "group lr 10^400": group(lr=huge),
        "group lr 1e300": group(lr=1e300),
        "group betas (NaN, 0.999)": group(betas=(math.nan, 0.999)),
        "group eps -1": group(eps=-1.0),
        "group weight_decay Inf": group(weight_decay=math.inf),
        "group maximize true": group(maximize=True),
        "avatar_config tau 10^400": lambda s: s.update(avatar_config=avatar),
    }
    return [(f"held-out error: {label}", case(change)) for label, change in cases.items()]


def heldout_checkpoint_cases(arrays: dict) -> list[tuple[str, bytes]]:
    from archhead_addon.io.checksum import KEY, with_checksum

    plain = {k: v for k, v in arrays.items() if k != KEY}
    config = json.loads(str(plain["config"]))
    config["tau"] = "__HUGE__"
    text = json.dumps(config).replace('"__HUGE__"', "1" + "0" * 400)
    return [("held-out error: config tau 10^400 with a valid checksum",
             npz_bytes(with_checksum({**plain, "config": np.str_(text)})))]  # fmt: skip


def heldout_ply_cases(data: bytes) -> list[tuple[str, bytes]]:
    """A count int() refuses (past 4300 digits), and f_rest counts of no SH degree."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header, body = data[:end].decode(), data[end:]
    table = np.frombuffer(body, F32).reshape(20, -1)
    names = [line.split()[2] for line in header.splitlines() if line.startswith("property")]
    keep = [i for i, n in enumerate(names) if not n.startswith("f_rest_")]
    out = [("held-out error: count of 5000 digits",
            header.replace("vertex 20", "vertex " + "9" * 5000).encode() + body)]  # fmt: skip
    for n_rest in (3, 30):
        at = [names[i] for i in keep].index("opacity")
        props = [names[i] for i in keep]
        props[at:at] = [f"f_rest_{i}" for i in range(n_rest)]
        cols = [table[:, keep[:at]], np.zeros((20, n_rest), F32), table[:, keep[at:]]]
        head = ["ply", "format binary_little_endian 1.0", "element vertex 20"]
        head += [f"property float {p}" for p in props] + ["end_header"]
        text = ("\n".join(head) + "\n").encode()
        out.append((f"held-out error: {n_rest} f_rest values (SH of {n_rest // 3 + 1})",
                    text + np.concatenate(cols, 1).tobytes()))  # fmt: skip
    return out


def many_frames(arrays: dict, frames: int, n: int) -> bytes:
    """`arrays` (n frames) repeated to `frames` frames, deflated: a small file of tens of
    MB of arrays, within zip_check's inflate floor (tests/test_size_bombs.py)."""
    reps = frames // n
    tiled = {
        k: np.tile(v, (reps,) + (1,) * (v.ndim - 1)) if v.ndim and len(v) == n else v
        for k, v in arrays.items()
    }
    return _zip_members([(f"{k}.npy", _npy(v)) for k, v in tiled.items()], zipfile.ZIP_DEFLATED)


# ------------------------------------------------------------------------- readers


def _reader(name):
    """The call a reader name stands for: path -> result (imports inside the worker)."""
    from archhead_addon.sequences import read_sequence

    if name in ("flame .npz", "flame .pkl"):
        from archhead_addon.flame.model import load_model

        return load_model
    if name == "canonical npz":
        return lambda p: read_sequence(p)
    if name in ("vhap folder", "vhap tracked npz"):
        return lambda p: read_sequence(p, "vhap", fps=25)
    if name == "metrical .frame":
        return lambda p: read_sequence(p, "metrical-tracker", fps=25)
    if name == "flame-head-tracker npz":
        return lambda p: read_sequence(p, "flame-head-tracker", fps=25)
    if name.startswith("driving clip"):
        return lambda p: read_sequence(p, "driving-clip")
    if name == "avatar checkpoint":
        from archhead_addon.avatar.checkpoint_format import read_checkpoint

        return read_checkpoint
    if name == "decode cache":
        from archhead_addon.avatar.decode_cache import DiskCache
        from archhead_addon.io.errors import InputError

        def cached(path):
            frame = DiskCache(Path(path).parent).get(Path(path).stem)
            if frame is None:
                raise InputError(path, None, "discarded by the cache (decoded again)")
            return frame

        return cached
    if name == "training config":
        from archhead_addon.train.config import TrainConfig

        return TrainConfig.load
    if name == "train_state":
        from archhead_addon.train.loop import load_state

        return load_state
    if name == "PLY":
        from archhead_addon.export.ply import read_ply, rows_to_gaussians

        return lambda p: rows_to_gaussians(read_ply(p), p)
    raise KeyError(name)


def corpus(root: Path) -> list[tuple[str, str, Path]]:
    """Write every reader's seed and malformed files under `root`: (reader, label, path).
    The seed of each reader is first, labelled 'seed'."""
    rng = np.random.default_rng(SEED)
    marker = root / "CODE_RAN"
    items = []

    def add(reader, label, data, name):
        folder = root / f"{len(items):05d}"
        folder.mkdir()
        path = folder / name
        path.write_bytes(data)
        items.append((reader, label, path))

    def family(reader, name, seed, mutations, extra=()):
        """`extra`: cases added later (issue 33), after the rounds, which are counted on
        `mutations` alone so that every earlier file stays as it was."""
        add(reader, "seed", seed, name)
        for round_ in range(2, 4):  # more byte damage for readers with few structured cases
            if len(mutations) < 110:
                more = byte_mutations(seed, rng)[1:]
                mutations = mutations + [(f"{label} (round {round_})", d) for label, d in more]
        for label, data in [*mutations, *extra]:
            add(reader, label, data, name)

    flame = _flame_arrays()
    family("flame .npz", "m.npz", npz_bytes(flame),
           npz_mutations(flame, rng) + byte_mutations(npz_bytes(flame), rng),
           heldout_npz_cases(flame))  # fmt: skip
    family("flame .pkl", "m.pkl", fast_pickle(flame),
           [(lbl, fast_pickle(d)) for lbl, d in value_mutations(flame, rng)]
           + pickle_mutations(flame, rng, marker, splice_pickle)
           + byte_mutations(fast_pickle(flame), rng),
           heldout_flame_pickle_cases(flame))  # fmt: skip
    seq = _sequence_arrays()
    family("canonical npz", "s.npz", npz_bytes(seq),
           npz_mutations(seq, rng) + byte_mutations(npz_bytes(seq), rng)
           + _canonical_cases(seq),
           heldout_npz_cases(seq) + heldout_camera_cases(seq))  # fmt: skip
    vt = _vhap_arrays(n=4)
    vt.update(focal_length=np.array([1.5], F32), image_size=np.array([256, 256]))
    family("vhap tracked npz", "tracked_flame_params.npz", npz_bytes(vt),
           npz_mutations(vt, rng) + byte_mutations(npz_bytes(vt), rng),
           heldout_npz_cases(vt))  # fmt: skip
    _vhap_folders(root, items, rng)
    frame = _metrical_frame()
    family("metrical .frame", "00001.frame", torch_bytes(frame),
           [(lbl, torch_bytes(d)) for lbl, d in value_mutations(frame, rng)]
           + pickle_mutations(frame, rng, marker, splice_torch)
           + zip_mutations(torch_bytes(frame)) + torch_size_bombs(torch_bytes(frame))
           + _metrical_cases(frame)
           + byte_mutations(torch_bytes(frame), rng),
           heldout_metrical_cases(frame))  # fmt: skip
    fht = _fht_arrays()
    family("flame-head-tracker npz", "3.npz", npz_bytes(fht),
           npz_mutations(fht, rng) + byte_mutations(npz_bytes(fht), rng),
           heldout_npz_cases(fht) + heldout_camera_cases(fht))  # fmt: skip
    clip = _clip()
    npz_clip = {**clip, "fps": np.float64(clip["fps"])}
    family("driving clip npz", "c.npz", npz_bytes(npz_clip),
           npz_mutations(npz_clip, rng) + byte_mutations(npz_bytes(npz_clip), rng),
           _clip_npz_cases(clip) + more_byte_mutations(npz_bytes(npz_clip), 1)
           + heldout_npz_cases(npz_clip))  # fmt: skip
    family("driving clip pkl", "c.pkl", fast_pickle(clip),
           [(lbl, fast_pickle(d)) for lbl, d in value_mutations(clip, rng)]
           + pickle_mutations(clip, rng, marker, splice_pickle)
           + byte_mutations(fast_pickle(clip), rng),
           _clip_pickle_cases(clip) + more_byte_mutations(fast_pickle(clip), 2)
           + [("held-out same: protocol 5", pickle.dumps(clip, protocol=5)),
              ("held-out same: an OrderedDict",
               pickle.dumps(collections.OrderedDict(clip), protocol=2))])  # fmt: skip
    family("driving clip .pt", "c.pt", torch_bytes(clip),
           [(lbl, torch_bytes(d)) for lbl, d in value_mutations(clip, rng)]
           + pickle_mutations(clip, rng, marker, splice_torch)
           + zip_mutations(torch_bytes(clip)) + torch_size_bombs(torch_bytes(clip))
           + byte_mutations(torch_bytes(clip), rng),
           [("held-out same: pickle protocol 5", _torch_protocol(clip, 5))])  # fmt: skip
    ckpt = _checkpoint_arrays()
    with np.load(__import__("io").BytesIO(ckpt)) as z:
        ckpt_arrays = {k: z[k] for k in z.files}
    family("avatar checkpoint", "a.npz", ckpt,
           npz_mutations(ckpt_arrays, rng) + byte_mutations(ckpt, rng)
           + [("older file, no checksum",
               npz_bytes({k: v for k, v in ckpt_arrays.items() if k != "checksum"}))],
           heldout_npz_cases(ckpt_arrays, checksummed=True)
           + heldout_checkpoint_cases(ckpt_arrays))  # fmt: skip
    cache = _cache_frame_bytes()
    with np.load(__import__("io").BytesIO(cache)) as z:
        cache_arrays = {k: z[k] for k in z.files}
    family("decode cache", "0123abcd.npz", cache,
           npz_mutations(cache_arrays, rng) + byte_mutations(cache, rng)
           + _cache_cases(cache_arrays),
           _cache_more_cases(cache_arrays) + more_byte_mutations(cache, 3)
           + heldout_npz_cases(cache_arrays, checksummed=True))  # fmt: skip
    config = _train_config()
    text = json.dumps(config).encode()
    tiny_tau = json.dumps({**config, "avatar": {**config["avatar"], "tau": 1e-300}}).encode()
    family("training config", "c.json", text,
           json_mutations(config, rng) + byte_mutations(text, rng)
           + [("avatar.tau 1e-300", tiny_tau)],
           heldout_json_cases(config))  # fmt: skip
    state_np = _train_state()
    family("train_state", "train_state.pt", torch_bytes(state_np),
           [(lbl, torch_bytes(d)) for lbl, d in value_mutations(state_np, rng)]
           + [(lbl, torch_bytes(d)) for lbl, d in _train_state_damage(state_np)]
           + pickle_mutations(state_np, rng, marker, splice_torch)
           + zip_mutations(torch_bytes(state_np)) + torch_size_bombs(torch_bytes(state_np))
           + byte_mutations(torch_bytes(state_np), rng),
           [(lbl, torch_bytes(d)) for lbl, d in _train_state_checksum_cases(state_np)]
           + heldout_state_cases(state_np))  # fmt: skip
    ply = _ply_bytes()
    family("PLY", "a.ply", ply,
           ply_mutations(ply, rng) + byte_mutations(ply, rng),
           ply_more_mutations(ply) + more_byte_mutations(ply, 4)
           + heldout_ply_cases(ply))  # fmt: skip
    return items


def _metrical_cases(frame: dict) -> list[tuple[str, bytes]]:
    """Degenerate 6D rotations (no rotation matrix at all), each alone in a good frame."""
    parallel = np.array([[0, 2, 0, 0, -1, 0]], F32)
    cases = {
        "flame.jaw 6D of zeros": ("jaw", np.zeros((1, 6), F32)),
        "flame.jaw 6D of two parallel vectors": ("jaw", parallel),
        "flame.eyes second 6D of zeros": ("eyes", np.array([[1, 0, 0, 0, 1, 0] + [0] * 6], F32)),
    }
    return [
        (label, torch_bytes({**frame, "flame": {**frame["flame"], key: value}}))
        for label, (key, value) in cases.items()
    ]


def _canonical_cases(seq: dict) -> list[tuple[str, bytes]]:
    """Finite values no camera has (validation.py): each alone in an otherwise good file."""
    negative = {**seq, "K": seq["K"].copy()}
    negative["K"][:, 0, 0] *= -1
    no_size = {k: v for k, v in seq.items() if k != "image_size"}
    return [
        ("K with a negative focal length", npz_bytes(negative)),
        ("K without image_size", npz_bytes(no_size)),
    ]


def _cache_cases(arrays: dict) -> list[tuple[str, bytes]]:
    """Cache frames whose checksum matches what they hold, every value impossible."""
    from archhead_addon.io.checksum import KEY, with_checksum

    plain = {k: v for k, v in arrays.items() if k != KEY}
    return [
        (f"resolution {r} with a valid checksum",
         npz_bytes(with_checksum({**plain, "resolution": np.int64(r)})))
        for r in (-1, 1 << 40)
    ]  # fmt: skip


def _numpy_tree(value):
    import torch

    if isinstance(value, torch.Tensor):
        return value.numpy()
    if isinstance(value, dict):
        return {k: _numpy_tree(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_numpy_tree(v) for v in value)
    return value


def _vhap_cases(transforms: dict, params: dict) -> list[tuple[str, str, bytes]]:
    """Folders whose files are each well formed and disagree, or hold impossible values."""
    import copy

    def changed(change):
        t = copy.deepcopy(transforms)
        change(t)
        return json.dumps(t).encode()

    wider = {**params, "expr": np.zeros((1, 7), F32), "shape": np.zeros(9, F32)}
    return [
        ("frame files of different widths", "flame_param/00001.npz", npz_bytes(wider)),
        ("a singular transform_matrix", "transforms.json",
         changed(lambda t: t["frames"][1].update(transform_matrix=np.zeros((4, 4)).tolist()))),
        ("timestep_index true (timestep 1 twice)", "transforms.json",
         changed(lambda t: t["frames"][0].update(timestep_index=True))),
        ("negative fl_x", "transforms.json", changed(lambda t: t.update(fl_x=-500.0))),
    ]  # fmt: skip


def _vhap_folders(root: Path, items: list, rng) -> None:
    """VHAP export folders: each with one damaged file (transforms.json or a flame_param)."""
    params = _vhap_arrays()
    transforms = _vhap_transforms()
    good_json = json.dumps(transforms).encode()
    variants = [("seed", "transforms.json", good_json)]
    variants += [(lbl, "transforms.json", d) for lbl, d in json_mutations(transforms, rng)[::3]]
    variants += [(lbl, "transforms.json", d) for lbl, d in byte_mutations(good_json, rng)[::2]]
    good = npz_bytes(params)
    variants += [(lbl, "flame_param/00001.npz", d) for lbl, d in npz_mutations(params, rng)[::2]]
    variants += [(lbl, "flame_param/00001.npz", d) for lbl, d in byte_mutations(good, rng)[::2]]
    variants += _vhap_cases(transforms, params) + _vhap_more_cases(transforms)
    variants += [(lbl, "transforms.json", d) for lbl, d in more_byte_mutations(good_json, 5)]
    huge = json.dumps(transforms).replace('"timestep_index": 1', '"timestep_index": 1' + "0" * 30)
    variants += [("held-out error: timestep_index 10^30", "transforms.json", huge.encode())]
    variants += [(lbl, "flame_param/00001.npz", d) for lbl, d in heldout_npz_cases(params)]
    for label, target, data in variants:
        folder = root / f"{len(items):05d}" / "vhap"
        (folder / "flame_param").mkdir(parents=True)
        (folder / "transforms.json").write_bytes(good_json)
        for t in range(2):
            (folder / f"flame_param/{t:05d}.npz").write_bytes(good)
        (folder / target).write_bytes(data)
        # the unchanged folder is the reader's seed: the others are compared with it
        items.append(("vhap folder", "seed" if label == "seed" else f"{target}: {label}", folder))


# ------------------------------------------------------------------------- running


def _size(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def _nonfinite(value, depth=0) -> bool:
    if depth > 6:
        return False
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "fc" and not np.isfinite(value).all()
    if isinstance(value, float):
        return not math.isfinite(value)
    if isinstance(value, dict):
        return any(_nonfinite(v, depth + 1) for v in value.values())
    if isinstance(value, list | tuple):
        return any(_nonfinite(v, depth + 1) for v in value[:1000])
    if is_dataclass(value):
        return any(_nonfinite(getattr(value, f.name), depth + 1) for f in fields(value))
    if hasattr(value, "numpy") and hasattr(value, "dtype"):  # torch tensors
        return _nonfinite(value.numpy(), depth)
    return False


def _equal(a, b, depth=0) -> bool:
    if depth > 6:
        return True
    if hasattr(a, "numpy") and hasattr(a, "dtype") and not isinstance(a, np.ndarray):
        a, b = a.numpy(), b.numpy()
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.shape == b.shape and np.array_equal(a, b)
    if isinstance(a, dict):
        return (
            isinstance(b, dict)
            and a.keys() == b.keys()
            and all(_equal(a[k], b[k], depth + 1) for k in a)
        )
    if isinstance(a, list | tuple):
        return (
            type(a) is type(b)
            and len(a) == len(b)
            and all(_equal(x, y, depth + 1) for x, y in zip(a, b, strict=True))
        )
    if is_dataclass(a):
        return type(a) is type(b) and all(
            _equal(getattr(a, f.name), getattr(b, f.name), depth + 1)
            for f in fields(a)
            if f.name not in ("source", "source_path")
        )
    return a == b or (a != a and b != b)


# Why a file may come back "changed": what its damage makes is a value no check can tell
# from a real one. Matched against the label's end (the first match names the reason).
INDISTINGUISHABLE = (
    (" -1", "every value -1: a plausible code, pose, translation or blendshape weight"),
    (" fractional", "every value +0.5: a plausible code, pose, translation or template shift"),
    (" fraction", "a loss weight of 2.5: a legal setting"),
    (" 0", "a step count or loss weight of 0: a legal setting (that part is off)"),
    (" dropped", "an optional key dropped: its default (or no eyelids / K from fov) is read"),
    (" list", "feature levels [1, 2]: legal sizes"),
    ("exp float16", "a clip saved in float16: read at that precision"),
    ("per-frame fl_x", "a frame's own focal length (nerfstudio's per-frame intrinsics)"),
    ("bit flip", "a flipped bit leaving a plausible number (mantissa, sign, small exponent)"),
    ("zeroed run", "zeroed bytes leaving exact zeros or plausible numbers"),
)


def indistinguishable(label: str) -> str:
    """The reason a changed file cannot be refused, or '' (then a check is missing)."""
    for pattern, reason in INDISTINGUISHABLE:
        if (
            pattern in label
            if pattern.startswith(("bit", "zeroed", "exp", "per"))
            else (label.endswith(pattern) or label.split(" (round")[0].endswith(pattern))
        ):
            return reason
    return ""


def _read_one(reader: str, path: Path):
    """(outcome kind, result, detail, peak bytes) of one read, in the worker."""
    from archhead_addon.io.errors import InputError, InputWarning

    read = _reader(reader)
    tracemalloc.start()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result = read(path)
                kind, detail = "ok", ""
            except InputError as exc:
                result, kind, detail = None, "error", str(exc)
            except Exception as exc:  # noqa: BLE001 - any other exception is what we count
                import traceback

                at = traceback.extract_tb(exc.__traceback__)[-1]
                where = f"{Path(at.filename).name}:{at.lineno}"
                result, kind, detail = None, "raw", f"{type(exc).__name__} at {where}: {exc}"
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    warned = [str(w.message) for w in caught if issubclass(w.category, InputWarning)]
    if kind == "ok" and warned:
        kind, detail = "warning", warned[0]
    return kind, result, detail[:300], peak


def _worker(conn):
    seeds = {}
    while True:
        job = conn.recv()
        if job is None:
            return
        reader, label, path = job
        kind, result, detail, peak = _read_one(reader, Path(path))
        if label == "seed":
            seeds[reader] = result
        nonfinite = kind in ("ok", "warning") and _nonfinite(result)
        same = kind == "ok" and reader in seeds and _equal(seeds[reader], result)
        conn.send((kind, detail, peak, nonfinite, same))


class _Worker:
    def __init__(self, ctx):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_worker, args=(child,), daemon=True)
        self.process.start()
        self.job = None

    def stop(self):
        self.process.kill()
        self.process.join()


def run(items, root: Path, workers: int = 2, time_limit: float = TIME_LIMIT_S) -> list[dict]:
    """Every item read by a pool of worker processes (one reader's items stay on one worker,
    after its seed); a read over `time_limit` kills its worker (outcome 'hang')."""
    ctx = multiprocessing.get_context("fork")
    marker = root / "CODE_RAN"
    sizes = {item[2]: _size(item[2]) for item in items}  # before readers delete any
    by_reader: dict[str, list] = {}
    for item in items:
        by_reader.setdefault(item[0], []).append(item)
    queues = [[] for _ in range(workers)]
    for group in sorted(by_reader.values(), key=len, reverse=True):
        min(queues, key=len).extend(group)
    results = []
    pool = [_Worker(ctx) for _ in range(workers)]
    positions = [0] * workers
    while any(positions[i] < len(queues[i]) or pool[i].job for i in range(workers)):
        for i, w in enumerate(pool):
            if w.job is None and positions[i] < len(queues[i]):
                w.job, w.started = queues[i][positions[i]], time.monotonic()
                positions[i] += 1
                w.conn.send((w.job[0], w.job[1], str(w.job[2])))
            if w.job is None:
                continue
            if w.conn.poll(0.002):
                kind, detail, peak, nonfinite, same = w.conn.recv()
                elapsed = time.monotonic() - w.started
            elif time.monotonic() - w.started > time_limit:
                w.stop()
                kind, detail, peak, nonfinite, same = "hang", "", 0, False, False
                elapsed = time_limit
                job = w.job
                pool[i] = w = _Worker(ctx)
                w.job = job
            else:
                continue
            reader, label, path = w.job
            w.job = None
            limit = ALLOC_FACTOR * sizes[path] + ALLOC_SLACK
            outcome = kind
            if kind in ("ok", "warning"):
                outcome = "warning" if kind == "warning" else ("same" if same else "changed")
            if outcome == "changed":
                detail = indistinguishable(label) or "NO REASON: a check may be missing"
            if nonfinite:
                outcome = "nonfinite"
            if peak > limit:
                outcome, detail = "alloc", f"peak {peak} bytes, limit {limit}"
            if marker.exists():
                outcome, detail = "code", f"{marker} exists"
                marker.unlink()
            results.append(dict(reader=reader, label=label, outcome=outcome, detail=detail,
                                seconds=elapsed, peak=peak))  # fmt: skip
    for w in pool:
        w.conn.send(None)
        w.process.join(5)
    return results


def table(results: list[dict]) -> str:
    """The markdown table of files tried per reader (seeds left out) and their outcomes."""
    rows = {}
    for r in results:
        if r["label"] != "seed":
            rows.setdefault(r["reader"], Counter())[r["outcome"]] += 1
    head = "| reader | files | " + " | ".join(OUTCOMES) + " | slowest s |"
    lines = [head, "|---" + "|---:" * (len(OUTCOMES) + 2) + "|"]
    for reader, counts in rows.items():
        slowest = max(r["seconds"] for r in results if r["reader"] == reader)
        cells = " | ".join(str(counts[o]) for o in OUTCOMES)
        lines.append(f"| {reader} | {sum(counts.values())} | {cells} | {slowest:.2f} |")
    total = sum(rows.values(), Counter())
    cells = " | ".join(str(total[o]) for o in OUTCOMES)
    slowest = max(r["seconds"] for r in results)
    lines.append(f"| all | {sum(total.values())} | {cells} | {slowest:.2f} |")
    return "\n".join(lines)


def main() -> int:
    """Generate the corpus in a temporary folder, run it, print the table (and, with -v,
    every file that was not refused or read cleanly)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as tmp:
        items = corpus(Path(tmp))
        results = run(items, Path(tmp))
    print(table(results))
    print(f"\n{len(results)} files in {time.monotonic() - start:.0f} s")
    if "-v" in sys.argv:
        for r in results:
            if r["outcome"] not in ("error", "same"):
                print(r["reader"], "|", r["label"], "|", r["outcome"], "|", r["detail"])
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    raise SystemExit(main())
