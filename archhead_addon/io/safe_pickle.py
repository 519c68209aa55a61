"""An allow-list unpickler for user files (FLAME pickles, tracker dumps).

`pickle.load` runs whatever callable a file names. This unpickler resolves only the names
below: numpy's array constructors, and stubs for chumpy and scipy.sparse objects (neither
package is imported; a stub keeps the pickled state and is turned into a numpy array).
Any other name is refused with an `InputError` before anything is called.

Sizes are bounded too (io/pickle_scan.py): the opcode stream is scanned before unpickling
(opcodes, memo entries, nesting), every array a constructor would allocate must fit in the
file's size (plus 1 MiB: a sparse matrix becomes dense), and the walk that resolves stubs
counts shared references each time they are reached.
"""

from __future__ import annotations

import collections
import functools
import io
import pickle
from pathlib import Path

import numpy as np

from .errors import InputError
from .pickle_scan import MAX_DEPTH, PickleLimitError, scan

_SLACK = 1 << 20  # bytes an array may exceed the file by (dense J_regressor, small arrays)


class _StateStub:
    """Instance of an allowed foreign class: keeps its pickled state, does nothing else."""

    def __init__(self, *args, **kwargs):
        self._args = args

    def __setstate__(self, state):
        if isinstance(state, tuple) and len(state) == 2:  # (dict, slots) form
            state = {**(state[0] or {}), **(state[1] or {})}
        self.__dict__["_state"] = state


class ChumpyStub(_StateStub):
    """A chumpy `Ch` (FLAME 2020 stores `shapedirs` and others this way); its value is `x`."""

    def to_array(self, where: str) -> np.ndarray:
        state = self.__dict__.get("_state")
        if isinstance(state, dict) and isinstance(state.get("x"), np.ndarray):
            return _plain(state["x"], where)
        raise ValueError(f"{where}: chumpy object without an 'x' array cannot be read")


class SparseStub(_StateStub):
    """A scipy.sparse CSC/CSR/COO matrix (FLAME 2023 stores `J_regressor` this way)."""

    fmt = "csc"

    def to_array(self, where: str, max_bytes: int) -> np.ndarray:
        s = self.__dict__.get("_state")
        if not isinstance(s, dict):
            raise ValueError(f"{where}: sparse matrix without state")
        shape = tuple(_count(n, where) for n in s.get("_shape", s.get("shape", ())))
        if len(shape) != 2:
            raise ValueError(f"{where}: sparse matrix has no 2-D shape")
        _check_size(shape, 8, max_bytes, where)
        data = _vector(s, "data", np.float64, where, "iuf")
        dense = np.zeros(shape, dtype=np.float64)
        if self.fmt == "coo":
            rows, cols = _vector(s, "row", np.int64, where), _vector(s, "col", np.int64, where)
        else:
            indices, indptr = (
                _vector(s, "indices", np.int64, where),
                _vector(s, "indptr", np.int64, where),
            )
            n_major = shape[1] if self.fmt == "csc" else shape[0]
            # the last entry counts the stored values: np.repeat below allocates that many
            if (
                len(indptr) != n_major + 1
                or (np.diff(indptr) < 0).any()
                or indptr[0] != 0
                or indptr[-1] != len(indices)
            ):
                raise ValueError(f"{where}: sparse matrix with an inconsistent indptr")
            major = np.repeat(np.arange(n_major), np.diff(indptr))
            rows, cols = (indices, major) if self.fmt == "csc" else (major, indices)
        if not len(rows) == len(cols) == len(data):
            raise ValueError(
                f"{where}: sparse matrix with {len(data)} values for {len(rows)} indices"
            )
        for axis, index in enumerate((rows, cols)):
            if len(index) and (index.min() < 0 or index.max() >= shape[axis]):
                raise ValueError(f"{where}: sparse matrix index outside its shape {shape}")
        np.add.at(dense, (rows, cols), data)
        return dense


def _count(n, where: str) -> int:
    if not isinstance(n, int | np.integer) or n < 0:
        raise ValueError(f"{where}: bad sparse matrix shape entry {n!r:.40}")
    return int(n)


def _vector(state: dict, key: str, dtype, where: str, kinds: str = "iu") -> np.ndarray:
    """A vector of the state: integers (indices), or `kinds` (values: no booleans, and
    no fractional indices, which a cast would truncate to other rows silently)."""
    value = state.get(key)
    if not isinstance(value, np.ndarray) or value.ndim != 1 or value.dtype.kind not in kinds:
        what = "an integer" if kinds == "iu" else "a numeric"
        raise ValueError(f"{where}: sparse matrix '{key}' is not {what} vector")
    return value.astype(dtype)


def _check_size(shape, itemsize: int, max_bytes: int, where: str) -> None:
    """Refuse an allocation a file of this size cannot hold (ints: no overflow)."""
    n = itemsize
    for d in shape:
        n *= int(d)
    if n > max_bytes:
        raise ValueError(
            f"{where}: an array of shape {tuple(shape)} ({n} bytes) is larger than the "
            f"file could hold ({max_bytes} bytes)"
        )


class _CscStub(SparseStub):
    fmt = "csc"


class _CsrStub(SparseStub):
    fmt = "csr"


class _CooStub(SparseStub):
    fmt = "coo"


def _latin1_encode(text, encoding="utf-8"):
    """`_codecs.encode` as protocol-2 pickles from Python 3 carry bytes (as latin1 text)."""
    if encoding not in ("latin1", "latin-1") or not isinstance(text, str):
        raise ValueError(f"_codecs.encode with {encoding!r} is not allowed")
    return text.encode("latin1")


class _SizedNdarray:
    """`numpy.ndarray` as a pickle names it. Called (REDUCE), an empty array whose size is
    checked first: unchecked, `ndarray((100000, 100000))` allocates 80 GB of address space
    and fails in numpy. Handed to a reconstructor, it stands for ndarray itself."""

    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes

    def __call__(self, shape, dtype=float, *rest, **options):
        if rest or options:
            raise pickle.UnpicklingError("ndarray from a buffer, offset or strides is not allowed")
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        if not all(isinstance(n, int) and n >= 0 for n in shape):
            raise pickle.UnpicklingError(f"ndarray shape {shape!r:.80} is not allowed")
        dtype = _checked_dtype(self.max_bytes, dtype)
        _check_size(shape, dtype.itemsize, self.max_bytes, "ndarray")
        return np.zeros(shape, dtype)


def _reconstructor(max_bytes, cls, base, state):
    """copyreg._reconstructor, restricted to classes this module already allowed."""
    cls = np.ndarray if isinstance(cls, _SizedNdarray) else cls
    if isinstance(cls, type) and issubclass(cls, _StateStub):
        return cls.__new__(cls)
    if cls is np.ndarray:
        shape, dtype = (tuple(state[0]), np.dtype(state[1])) if state else ((0,), np.float64)
        _check_size(shape, np.dtype(dtype).itemsize, max_bytes, "ndarray")
        return np.ndarray.__new__(cls, shape, dtype)
    raise pickle.UnpicklingError(f"reconstruction of {cls!r} is not allowed")


def _checked_reconstruct(max_bytes, subtype, shape, dtype):
    """numpy's `_reconstruct` (an empty array that BUILD then fills), its size bounded."""
    subtype = np.ndarray if isinstance(subtype, _SizedNdarray) else subtype
    if subtype is not np.ndarray:
        raise pickle.UnpicklingError(f"numpy reconstruction of {subtype!r} is not allowed")
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    dtype = _checked_dtype(max_bytes, dtype)
    _check_size(shape, dtype.itemsize, max_bytes, "ndarray")
    return np.ndarray.__new__(subtype, shape, dtype)


def _checked_dtype(max_bytes, *args):
    dtype = np.dtype(*args)
    if dtype.hasobject or dtype.itemsize > max_bytes:
        raise pickle.UnpicklingError(f"dtype {dtype} is not allowed")
    return dtype


def _checked_bytearray(max_bytes, *args):
    if args and not isinstance(args[0], bytes | bytearray | str):
        raise pickle.UnpicklingError("bytearray from anything but bytes is not allowed")
    return bytearray(*args)


def _numpy_names() -> dict[tuple[str, str], object]:
    try:
        from numpy._core import multiarray  # numpy 2
    except ImportError:
        from numpy.core import multiarray  # numpy 1.x

    names: dict[tuple[str, str], object] = {}
    for mod in ("numpy.core.multiarray", "numpy._core.multiarray"):
        names[(mod, "scalar")] = multiarray.scalar
    for mod in ("numpy.core.numeric", "numpy._core.numeric"):
        names[(mod, "_frombuffer")] = _frombuffer
    return names


def _frombuffer(buf, dtype, shape, order):
    array = np.frombuffer(buf, dtype=dtype)
    return array.reshape(shape, order=order).copy()


_SPARSE = {
    "csc_matrix": _CscStub,
    "csc_array": _CscStub,
    "csr_matrix": _CsrStub,
    "csr_array": _CsrStub,
    "coo_matrix": _CooStub,
    "coo_array": _CooStub,
}

_BUILTINS = {
    "object": object,
    "set": set,
    "frozenset": frozenset,
    "complex": complex,
    "slice": slice,
}


class RestrictedUnpickler(pickle.Unpickler):
    """Resolves only allow-listed names; `extra` adds (module, name) -> object pairs.
    Constructors that allocate refuse arrays above `max_bytes`."""

    def __init__(self, file, *, source="<input>", extra=None, max_bytes=_SLACK, **kwargs):
        kwargs.setdefault("encoding", "latin1")  # Python 2 pickles (FLAME 2020)
        super().__init__(file, **kwargs)
        self._source = source
        sized = {
            ("numpy", "dtype"): _checked_dtype,
            ("builtins", "bytearray"): _checked_bytearray,
            ("__builtin__", "bytearray"): _checked_bytearray,
            ("copy_reg", "_reconstructor"): _reconstructor,
            ("copyreg", "_reconstructor"): _reconstructor,
            ("numpy.core.multiarray", "_reconstruct"): _checked_reconstruct,
            ("numpy._core.multiarray", "_reconstruct"): _checked_reconstruct,
        }
        self._allowed = {
            **_numpy_names(),
            **{k: functools.partial(f, max_bytes) for k, f in sized.items()},
            ("numpy", "ndarray"): _SizedNdarray(max_bytes),
            # a dict saved as an OrderedDict (as torch.save files hold them): read as a dict
            ("collections", "OrderedDict"): collections.OrderedDict,
            **(extra or {}),
        }

    def find_class(self, module: str, name: str):
        if (module, name) in self._allowed:
            return self._allowed[(module, name)]
        if module in ("__builtin__", "builtins") and name in _BUILTINS:
            return _BUILTINS[name]
        if (module, name) == ("_codecs", "encode"):
            return _latin1_encode
        if module == "chumpy" or module.startswith("chumpy."):
            return ChumpyStub
        if module.startswith("scipy.sparse") and name in _SPARSE:
            return _SPARSE[name]
        raise InputError(
            self._source,
            None,
            f"pickle refers to '{module}.{name}', which is not on the allow-list "
            "of classes this reader accepts; nothing was executed",
        )


def _plain(array: np.ndarray, where: str) -> np.ndarray:
    if array.dtype.hasobject:
        raise ValueError(f"{where}: an array of Python objects is not read")
    return array


def resolve(obj, where: str = "<input>", max_bytes: int = _SLACK, seen=None, depth=0):
    """Turn stubs into numpy arrays, recursively through dicts, lists and tuples. A container
    reached twice is refused: no file ArchHead reads shares one, and sharing is what lets a
    few hundred bytes stand for 2^40 elements (a "billion laughs" graph)."""
    seen = {} if seen is None else seen
    if depth > MAX_DEPTH:
        raise PickleLimitError(f"containers nested deeper than {MAX_DEPTH}")
    if _holds_objects(obj):
        if id(obj) in seen:
            raise PickleLimitError(
                "one object is referenced from several places "
                "(shared references multiply it: a 'billion laughs' graph?)"
            )
        seen[id(obj)] = obj  # kept alive, so its id is not reused during the walk
    if isinstance(obj, ChumpyStub):
        return obj.to_array(where)
    if isinstance(obj, SparseStub):
        return obj.to_array(where, max_bytes)
    if isinstance(obj, np.ndarray):
        return _plain(obj, where)
    if isinstance(obj, dict):
        return {
            k: resolve(v, f"{where}[{k!r:.40}]", max_bytes, seen, depth + 1) for k, v in obj.items()
        }
    if isinstance(obj, list | tuple):
        return type(obj)(resolve(v, where, max_bytes, seen, depth + 1) for v in obj)
    return obj


def _holds_objects(obj) -> bool:
    """Stubs, dicts and lists with items, and tuples holding any of those."""
    if isinstance(obj, _StateStub):
        return True
    if isinstance(obj, tuple):
        return any(isinstance(v, dict | list | tuple | _StateStub) for v in obj)
    return isinstance(obj, dict | list) and len(obj) > 0


# What a malformed stream raises inside the unpickler or the stubs' conversion.
UNPICKLE_ERRORS = (
    pickle.UnpicklingError,
    EOFError,
    ValueError,
    TypeError,
    AttributeError,
    IndexError,
    KeyError,
    UnicodeDecodeError,
    OverflowError,
    RecursionError,
    SystemError,  # numpy's dtype.__setstate__ on arguments it does not expect
)


def unpickle(data: bytes, name: str, *, unpickler=RestrictedUnpickler, max_bytes=None, **kwargs):
    """Scan (pickle_scan.scan), unpickle and resolve `data`; InputError on any failure.
    Arrays may take `max_bytes` (default: the pickle's size plus 1 MiB)."""
    max_bytes = max_bytes or len(data) + _SLACK
    try:
        scan(data)
        obj = unpickler(io.BytesIO(data), source=name, max_bytes=max_bytes, **kwargs).load()
        return resolve(obj, name, max_bytes)
    except InputError:
        raise
    except PickleLimitError as exc:
        raise InputError(name, None, f"refused: {exc}") from exc
    except UNPICKLE_ERRORS as exc:
        raise InputError(
            name, None, f"not a readable pickle ({type(exc).__name__}: {exc})"
        ) from exc


def safe_load(source, *, extra=None, **kwargs):
    """Load a pickle (path, bytes or binary file) through the allow-list; stubs resolved."""
    name = "<bytes>"
    if isinstance(source, (str, Path)):
        name = str(source)
        try:
            data = Path(source).read_bytes()
        except OSError as exc:
            raise InputError(name, None, f"unreadable ({exc})") from exc
    elif isinstance(source, (bytes, bytearray)):
        data = bytes(source)
    else:
        name = getattr(source, "name", name)
        data = source.read()
    return unpickle(data, name, extra=extra, **kwargs)
