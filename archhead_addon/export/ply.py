"""The standard 3DGS PLY (as written by the original implementation, read by splat viewers).

One `vertex` element, binary little endian, float32 properties in this order:
  x y z            mean
  nx ny nz         zeros (3DGS writes them; viewers ignore them)
  f_dc_0..2        SH DC coefficients, r g b
  f_rest_0..44     higher SH bands channel-major: f_rest[c * 15 + k] = sh[:, 1 + k, c]
  opacity          logit
  scale_0..2       log standard deviations
  rot_0..3         quaternion w, x, y, z
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_path
from ..io.errors import InputError
from ..io.schema import F32_TINY, check_finite, check_range, flush_subnormal

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "<i2",
    "int16": "<i2",
    "ushort": "<u2",
    "uint16": "<u2",
    "int": "<i4",
    "int32": "<i4",
    "uint": "<u4",
    "uint32": "<u4",
    "float": "<f4",
    "float32": "<f4",
    "double": "<f8",
    "float64": "<f8",
}


def property_names(n_rest: int) -> list[str]:
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity"]
        + [f"scale_{i}" for i in range(3)]
        + [f"rot_{i}" for i in range(4)]
    )


def gaussians_to_rows(means, log_scales, quats, opacity_logits, sh) -> np.ndarray:
    """(N, 17 + 3 (K - 1)) float32 rows in `property_names` order; sh is (N,K,3)."""
    sh = np.asarray(sh, np.float32)
    n = len(sh)
    rest = np.swapaxes(sh[:, 1:], 1, 2).reshape(n, -1)  # (N, 3, K-1): channel-major
    return np.concatenate(
        [
            np.asarray(means, np.float32),
            np.zeros((n, 3), np.float32),
            sh[:, 0],
            rest,
            np.asarray(opacity_logits, np.float32)[:, None],
            np.asarray(log_scales, np.float32),
            np.asarray(quats, np.float32),
        ],
        axis=1,
    )


def write_ply(path, means, log_scales, quats, opacity_logits, sh) -> None:
    """Write atomically (a reader never sees a torn file)."""
    rows = gaussians_to_rows(means, log_scales, quats, opacity_logits, sh)
    names = property_names(rows.shape[1] - 17)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(rows)}"]
    header += [f"property float {name}" for name in names] + ["end_header"]
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(np.ascontiguousarray(rows, "<f4").tobytes())


MAX_HEADER = 1 << 16


def read_ply(path) -> dict[str, np.ndarray]:
    """The vertex properties of a binary little-endian PLY, by name (any scalar types);
    float properties must be finite. InputError names the file and the property."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, None, f"unreadable ({exc})") from exc
    end = data.find(b"end_header", 0, MAX_HEADER)
    if not data.startswith(b"ply") or end < 0 or data.find(b"\n", end) < 0:
        raise InputError(path, None, "not a PLY file (no 'ply' magic or no end_header)")
    body = data.index(b"\n", end) + 1
    fields, count, last = _header(path, data[:body].decode("ascii", "replace").splitlines())
    dtype = np.dtype(fields)
    need, have = count * dtype.itemsize, len(data) - body
    # elements after the vertices (faces) hold more bytes; with none, the sizes must agree
    if have < need or (last and have != need):
        raise InputError(
            path,
            "element vertex",
            f"{count} vertices of {dtype.itemsize} bytes need {need} bytes, the body holds "
            f"{have}: " + ("truncated" if have < need else "the header's count or properties "
                           "disagree with the body"),
        )  # fmt: skip
    table = np.frombuffer(data, dtype, count, body)
    out = {name: table[name].copy() for name, _ in fields}
    for name, value in out.items():
        check_finite(value, path, name, along="vertex")
        out[name] = flush_subnormal(value, path, name)
    return out


def _header(path, lines: list[str]) -> tuple[list, int]:
    if "format binary_little_endian 1.0" not in lines:
        raise InputError(path, "format", "only binary_little_endian PLY files are read")
    fields, count, element, last = [], None, None, True
    for line in lines:
        tokens = line.split()
        if not line.isascii() or not line.isprintable():
            raise InputError(path, "header", f"bytes that are not text in line {line[:60]!r}")
        if tokens[:1] and tokens[0] not in _HEADER_WORDS:
            raise InputError(path, "header", f"unknown line {line[:60]!r}")
        if tokens[:1] == ["element"]:
            if len(tokens) != 3 or not tokens[2].isdigit():
                raise InputError(path, "element", f"malformed line {line[:60]!r}")
            if len(tokens[2]) > MAX_COUNT_DIGITS:  # int() refuses past 4300 digits
                raise InputError(
                    path,
                    f"element {tokens[1]}",
                    f"a count of {len(tokens[2])} digits: more than any file holds",
                )
            element = tokens[1]
            if element == "vertex":
                count = int(tokens[2])
            elif count is None:
                raise InputError(path, f"element {element}", "the vertex element must come first")
            else:
                last = False
                break  # elements after the vertices are not read
        elif tokens[:1] == ["property"] and element == "vertex":
            if len(tokens) != 3 or tokens[1] not in _PLY_TYPES:
                raise InputError(path, tokens[-1], f"unsupported property {line[:60]!r}")
            if tokens[2] in {name for name, _ in fields}:
                raise InputError(path, tokens[2], "property given twice")
            fields.append((tokens[2], _PLY_TYPES[tokens[1]]))
    if count is None:
        raise InputError(path, "element vertex", "missing")
    if not fields:
        raise InputError(path, "element vertex", "has no properties")
    return fields, count, last


MAX_COUNT_DIGITS = 18  # below 2^63: larger counts are refused by the body's size anyway
_HEADER_WORDS = {"ply", "format", "comment", "obj_info", "element", "property", "end_header"}


def rows_to_gaussians(props: dict[str, np.ndarray], path=None) -> dict[str, np.ndarray]:
    """`read_ply` output back to means, log_scales, quats, opacity_logits, sh (N,K,3).
    Missing properties and quaternions no float32 renderer can normalise (norm outside
    QUAT_NORM) are InputErrors; values past plausible ranges
    (a bit flip in a float's exponent, usually) give an InputWarning."""
    n_rest = len([k for k in props if re.fullmatch(r"f_rest_\d+", k)])
    if n_rest % 3:
        raise InputError(path, "f_rest", f"{n_rest} higher SH values: not 3 per band")
    if n_rest // 3 + 1 not in SH_COEFFICIENTS:  # K = (degree + 1)^2, as decode_cache reads
        raise InputError(
            path,
            "f_rest",
            f"{n_rest} higher SH values: {n_rest // 3 + 1} coefficients per colour, not an "
            f"SH degree's {SH_COEFFICIENTS} (degree 0..3)",
        )

    def stack(names):
        for name in names:
            if name not in props:
                raise InputError(path, name, "missing")
        return np.stack([props[k] for k in names], axis=1).astype(np.float32)

    dc = stack([f"f_dc_{i}" for i in range(3)])
    rest = stack([f"f_rest_{i}" for i in range(n_rest)]) if n_rest else np.zeros((len(dc), 0))
    out = {
        "means": stack("xyz"),
        "log_scales": stack([f"scale_{i}" for i in range(3)]),
        "quats": stack([f"rot_{i}" for i in range(4)]),
        "opacity_logits": stack(["opacity"])[:, 0],
        "sh": np.concatenate(
            [dc[:, None], np.swapaxes(rest.reshape(len(dc), 3, n_rest // 3), 1, 2)], axis=1
        ),
    }
    # renderers normalise q in float32: its squared norm must be a normal, finite float32
    norm = np.linalg.norm(out["quats"].astype(np.float64), axis=1)
    bad = ~((norm >= QUAT_NORM[0]) & (norm <= QUAT_NORM[1]))
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(
            path,
            "rot_0",
            f"{'zero ' if norm[i] == 0 else ''}quaternion of norm {norm[i]:.3g} at vertex index "
            f"{i}: outside {QUAT_NORM[0]:.2g}..{QUAT_NORM[1]:.2g}, where normalising it in "
            "float32 divides by zero or Inf",
        )
    for key, limit, reason in _PLAUSIBLE:
        check_range(out[key], path, key, plausible=limit, reason=reason)
    return out


SH_COEFFICIENTS = (1, 4, 9, 16)
QUAT_NORM = (float(np.sqrt(F32_TINY)), float(np.sqrt(np.finfo(np.float32).max)))
_PLAUSIBLE = (
    ("means", 1e3, "metres from the origin"),
    ("log_scales", 20.0, "log standard deviations; e^20 m"),
    ("opacity_logits", 1e3, "logits; beyond ±20 the opacity is 0 or 1 anyway"),
    ("sh", 1e3, "SH colour coefficients"),
)
