"""Read files written by `torch.save` (the zip format, torch >= 1.6) into numpy, without torch.

Blender's Python never imports torch, yet it must read tracker dumps such as metrical-tracker's
`.frame` files. Such a file is a zip archive whose entries share one folder `<name>/`:

- `data.pkl`: the pickled object (protocol 2);
- `data/<key>`: the raw bytes of each storage;
- `byteorder`: "little" or "big" (absent in old files: little);
- `version`, `.format_version`, `.data/serialization_id`, ...: bookkeeping, not needed here.

Inside `data.pkl` a tensor is `torch._utils._rebuild_tensor_v2(storage, offset, size, stride,
requires_grad, hooks[, metadata])`, where `storage` is a persistent id `('storage',
torch.<Type>Storage, key, location, numel)`. Dtypes newer than the typed storages (uint16/32/64)
use `_rebuild_tensor_v3(..., dtype)` over a byte storage (`torch.storage.UntypedStorage`). An
`nn.Parameter` wraps such a tensor in `_rebuild_parameter`.

The pickle goes through the project's allow-list unpickler: exactly these torch names are mapped
to functions that build numpy arrays (bounds-checked views of the storage bytes, then copied);
every other name is refused before anything is called. Tensors come back as numpy arrays
(bfloat16 as float32, the only lossless numpy type for it); numpy arrays inside stay arrays.
The legacy pre-1.6 format (one pickle stream, no zip) is refused with a message saying so.
The archive's directory is checked first (io/zip_check.py), the pickle is bounded like any
other (io/pickle_scan.py), and no tensor may need more bytes than the archive holds (zero
strides let a few stored bytes claim a huge tensor). Members are read up to their declared
size, each size checked first (a storage against its persistent id's element count and the
file's size), never through `ZipFile.read`, which inflates up to 1 GiB before it cuts.
"""

from __future__ import annotations

import collections
import functools
import math
import pickle
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .errors import InputError
from .safe_pickle import RestrictedUnpickler, unpickle
from .zip_check import open_checked

# torch.save's legacy format starts with a pickled int, this magic number (protocol 2, LONG1).
_LEGACY_MAGIC = b"\x80\x02\x8a\x0a" + (0x1950A86A20F9469CFC6C).to_bytes(10, "little")

_TYPED_STORAGES = {
    "DoubleStorage": "f8",
    "FloatStorage": "f4",
    "HalfStorage": "f2",
    "BFloat16Storage": "u2",
    "LongStorage": "i8",
    "IntStorage": "i4",
    "ShortStorage": "i2",
    "CharStorage": "i1",
    "ByteStorage": "u1",
    "BoolStorage": "?",
    "ComplexDoubleStorage": "c16",
    "ComplexFloatStorage": "c8",
}
_V3_DTYPES = {"uint16": "u2", "uint32": "u4", "uint64": "u8"}


class _StorageType:
    """Stands for `torch.<Name>Storage` (or UntypedStorage, as bytes) in the pickle."""

    def __init__(self, name: str, code: str):
        self.name, self.dtype = name, np.dtype("<" + code)


class _TorchDtype:
    """Stands for a `torch.<dtype>` global (only the v3 ones above are allowed)."""

    def __init__(self, code: str):
        self.dtype = np.dtype("<" + code)


class _Storage:
    """One storage's elements as a flat read-only numpy array."""

    def __init__(
        self, array: np.ndarray, max_bytes: int, bfloat16: bool = False, big_endian: bool = False
    ):
        self.array, self.bfloat16, self.big_endian = array, bfloat16, big_endian
        self.max_bytes = max_bytes

    def view(self, offset, size, stride) -> np.ndarray:
        """The tensor `as_strided(storage, size, stride, offset)`, checked against the bounds."""
        size, stride = _int_tuple(size, "size"), _int_tuple(stride, "stride")
        if len(size) != len(stride) or not isinstance(offset, int) or offset < 0:
            raise ValueError(f"bad tensor layout: offset {offset}, size {size}, stride {stride}")
        if math.prod(size) * self.array.itemsize > self.max_bytes:
            raise ValueError(f"tensor of size {size} needs more bytes than the file holds")
        if 0 in size:
            out = np.empty(size, dtype=self.array.dtype)
        else:
            last = offset + sum((n - 1) * s for n, s in zip(size, stride, strict=True))
            if last >= self.array.size:
                raise ValueError(
                    f"tensor (offset {offset}, size {size}, stride {stride}) reaches "
                    f"element {last} of a storage of {self.array.size} elements"
                )
            item = self.array.itemsize
            out = np.lib.stride_tricks.as_strided(
                self.array[offset:], size, [s * item for s in stride], writeable=False
            ).copy()
        out = out.astype(out.dtype.newbyteorder("="), copy=False)
        if self.bfloat16:  # bfloat16 is the upper half of a float32
            out = (out.astype(np.uint32) << 16).view(np.float32)
        return out


def _int_tuple(values, what: str) -> tuple[int, ...]:
    if not isinstance(values, tuple | list) or not all(
        isinstance(v, int) and v >= 0 for v in values
    ):
        raise ValueError(f"bad tensor {what}: {values!r:.80}")
    return tuple(values)


def _rebuild_tensor_v2(
    storage, offset, size, stride, requires_grad=False, hooks=None, metadata=None
):
    if not isinstance(storage, _Storage):
        raise ValueError("tensor without a storage")
    return storage.view(offset, size, stride)


def _rebuild_tensor_v3(storage, offset, size, stride, requires_grad, hooks, dtype, metadata=None):
    if not isinstance(storage, _Storage) or not isinstance(dtype, _TorchDtype):
        raise ValueError("tensor without a byte storage and dtype")
    raw = storage.array
    usable = raw.size - raw.size % dtype.dtype.itemsize
    typed = raw[:usable].view(dtype.dtype.newbyteorder(">" if storage.big_endian else "<"))
    return _Storage(typed, storage.max_bytes).view(offset, size, stride)


def _rebuild_parameter(data, requires_grad, hooks, state=None):
    return data


ALLOWED_NAMES: dict[tuple[str, str], object] = {
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor_v2,
    ("torch._utils", "_rebuild_tensor_v3"): _rebuild_tensor_v3,
    ("torch._utils", "_rebuild_parameter"): _rebuild_parameter,
    ("torch._utils", "_rebuild_parameter_with_state"): _rebuild_parameter,
    ("torch.storage", "UntypedStorage"): _StorageType("UntypedStorage", "u1"),
    ("collections", "OrderedDict"): collections.OrderedDict,
    **{("torch", name): _StorageType(name, code) for name, code in _TYPED_STORAGES.items()},
    **{("torch", name): _TorchDtype(code) for name, code in _V3_DTYPES.items()},
}
"""Every name a torch.save pickle may use."""


class _TorchUnpickler(RestrictedUnpickler):
    def __init__(self, file, *, archive, prefix: str, big_endian: bool, source, max_bytes):
        super().__init__(file, source=source, extra=ALLOWED_NAMES, max_bytes=max_bytes)
        self._archive, self._prefix, self._big = archive, prefix, big_endian
        self._max_bytes = max_bytes
        self._storages: dict[str, _Storage] = {}

    def persistent_load(self, pid):
        if not (
            isinstance(pid, tuple)
            and len(pid) == 5
            and pid[0] == "storage"
            and isinstance(pid[1], _StorageType)
            and isinstance(pid[2], str)
            and isinstance(pid[4], int)
            and 0 <= pid[4] * pid[1].dtype.itemsize <= self._max_bytes
        ):
            raise pickle.UnpicklingError(f"unsupported persistent id {pid!r:.80}")
        _, stype, key, _location, numel = pid
        if key not in self._storages:
            dtype = stype.dtype.newbyteorder(">") if self._big else stype.dtype
            name = f"{self._prefix}data/{key}"
            try:
                info = self._archive.getinfo(name)
            except KeyError:
                raise ValueError(f"storage '{key}' is missing from the archive") from None
            if info.file_size != numel * dtype.itemsize:  # from the directory, nothing read
                raise ValueError(
                    f"storage '{key}' holds {info.file_size} bytes, not the "
                    f"{numel} elements of {stype.name} its tensor's pickle declares"
                )
            raw = read_member(self._archive, info, self._max_bytes)
            array = np.frombuffer(raw, dtype=dtype, count=numel)
            self._storages[key] = _Storage(
                array,
                self._max_bytes,
                bfloat16=stype.name == "BFloat16Storage",
                big_endian=self._big,
            )
        return self._storages[key]


def looks_like_torch_file(path) -> bool:
    """True for a zip archive or a legacy torch.save stream (both go to `load_torch_file`)."""
    with open(path, "rb") as f:
        head = f.read(len(_LEGACY_MAGIC))
    return head.startswith(b"PK") or head == _LEGACY_MAGIC


def load_torch_file(path):
    """The object saved by `torch.save` at `path`, tensors as numpy arrays."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "file not found")
    if not zipfile.is_zipfile(path):
        with open(path, "rb") as f:
            head = f.read(len(_LEGACY_MAGIC))
        if head == _LEGACY_MAGIC:
            raise InputError(
                path,
                None,
                "legacy torch.save format (before torch 1.6, not a zip "
                "archive) is not supported; load it with torch and save it again",
            )
        raise InputError(
            path, None, "not a torch.save zip archive (truncated or another kind of file)"
        )
    max_bytes = path.stat().st_size + (1 << 20)
    with open_checked(path, what="torch.save archive") as archive:
        try:
            data, prefix, big = _pickle_entry(archive, path)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, UnicodeDecodeError) as exc:
            raise InputError(
                path, None, f"corrupt torch.save archive ({type(exc).__name__}: {exc})"
            ) from exc
        unpickler = functools.partial(
            _TorchUnpickler, archive=archive, prefix=prefix, big_endian=big
        )
        try:
            return unpickle(data, str(path), unpickler=unpickler, max_bytes=max_bytes)
        except InputError as exc:
            if exc.path == str(path) and exc.problem.startswith("not a readable pickle"):
                raise InputError(path, None, "corrupt torch.save archive: " + exc.problem) from exc
            raise
        except (zipfile.BadZipFile, zlib.error, OSError) as exc:  # a storage fails its CRC
            raise InputError(
                path, None, f"corrupt torch.save archive ({type(exc).__name__}: {exc})"
            ) from exc


def _pickle_entry(archive: zipfile.ZipFile, path) -> tuple[bytes, str, bool]:
    """data.pkl's bytes, the archive's folder prefix and whether it is big-endian."""
    pickles = [n for n in archive.namelist() if n.endswith("/data.pkl") and n.count("/") == 1]
    if len(pickles) != 1:
        raise InputError(
            path,
            None,
            f"expected one '<name>/data.pkl' entry in the zip archive, found {len(pickles)}",
        )
    prefix = pickles[0][: -len("data.pkl")]
    limit = path.stat().st_size + (1 << 20)
    order = "little"
    if prefix + "byteorder" in archive.namelist():
        raw = read_member(archive, archive.getinfo(prefix + "byteorder"), 64, path)
        order = raw.decode("ascii", "replace").strip()
    if order not in ("little", "big"):
        raise InputError(path, None, f"unknown byteorder '{order:.40}' in the archive")
    return read_member(archive, archive.getinfo(pickles[0]), limit, path), prefix, order == "big"


def read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, limit: int, path=None) -> bytes:
    """A member's bytes, at most its declared size, refused above `limit` before a byte is
    inflated. `ZipFile.read` inflates up to 1 GiB per call whatever the directory declares,
    then cuts it to the declared size: a lying directory costs gigabytes there (issue 33).
    InputError naming the member when `path` is given, else ValueError (inside the pickle)."""
    problem = None
    if info.file_size > limit:
        problem = f"member of {info.file_size} bytes, above this file's limit of {limit}"
    else:
        with archive.open(info) as f:
            data = f.read(info.file_size)
            f.read(1)  # at the end: checks the CRC
        if len(data) != info.file_size:
            problem = f"member ends after {len(data)} of its {info.file_size} bytes"
    if problem is None:
        return data
    if path is None:
        raise ValueError(f"{info.filename}: {problem}")
    raise InputError(path, info.filename, problem)
