"""An allow-list unpickler for user files (FLAME pickles, tracker dumps).

`pickle.load` runs whatever callable a file names. This unpickler resolves only the names
below: numpy's array constructors, and stubs for chumpy and scipy.sparse objects (neither
package is imported; a stub keeps the pickled state and is turned into a numpy array).
Any other name is refused with an `InputError` before anything is called.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np

from .errors import InputError


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
        if isinstance(state, dict) and "x" in state:
            return np.asarray(resolve(state["x"], where))
        raise ValueError(f"{where}: chumpy object without an 'x' array cannot be read")


class SparseStub(_StateStub):
    """A scipy.sparse CSC/CSR/COO matrix (FLAME 2023 stores `J_regressor` this way)."""

    fmt = "csc"

    def to_array(self, where: str) -> np.ndarray:
        s = self.__dict__.get("_state")
        if not isinstance(s, dict):
            raise ValueError(f"{where}: sparse matrix without state")
        shape = tuple(int(n) for n in s.get("_shape", s.get("shape", ())))
        if len(shape) != 2:
            raise ValueError(f"{where}: sparse matrix has no 2-D shape")
        data = np.asarray(s["data"], dtype=np.float64)
        dense = np.zeros(shape, dtype=np.float64)
        if self.fmt == "coo":
            np.add.at(dense, (np.asarray(s["row"]), np.asarray(s["col"])), data)
            return dense
        indices, indptr = np.asarray(s["indices"]), np.asarray(s["indptr"])
        major = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        if self.fmt == "csc":  # indptr runs over columns
            np.add.at(dense, (indices, major), data)
        else:
            np.add.at(dense, (major, indices), data)
        return dense


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


def _reconstructor(cls, base, state):
    """copyreg._reconstructor, restricted to classes this module already allowed."""
    if isinstance(cls, type) and issubclass(cls, _StateStub):
        return cls.__new__(cls)
    if cls is np.ndarray:
        return np.ndarray.__new__(cls, *(state or ((0,), np.float64)))
    raise pickle.UnpicklingError(f"reconstruction of {cls!r} is not allowed")


def _numpy_names() -> dict[tuple[str, str], object]:
    names: dict[tuple[str, str], object] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
    }
    try:
        from numpy._core import multiarray  # numpy 2
    except ImportError:
        from numpy.core import multiarray  # numpy 1.x

    for mod in ("numpy.core.multiarray", "numpy._core.multiarray"):
        names[(mod, "_reconstruct")] = multiarray._reconstruct
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
    "bytearray": bytearray,
    "complex": complex,
    "slice": slice,
}


class RestrictedUnpickler(pickle.Unpickler):
    """Resolves only allow-listed names; `extra` adds (module, name) -> object pairs."""

    def __init__(self, file, *, source="<input>", extra=None, **kwargs):
        kwargs.setdefault("encoding", "latin1")  # Python 2 pickles (FLAME 2020)
        super().__init__(file, **kwargs)
        self._source = source
        self._allowed = {**_numpy_names(), **(extra or {})}

    def find_class(self, module: str, name: str):
        if (module, name) in self._allowed:
            return self._allowed[(module, name)]
        if module in ("copy_reg", "copyreg") and name == "_reconstructor":
            return _reconstructor
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


def resolve(obj, where: str = "<input>"):
    """Turn stubs into numpy arrays, recursively through dicts, lists and tuples."""
    if isinstance(obj, (ChumpyStub, SparseStub)):
        return obj.to_array(where)
    if isinstance(obj, dict):
        return {k: resolve(v, f"{where}[{k!r}]") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(resolve(v, where) for v in obj)
    return obj


def safe_load(source, *, extra=None, **kwargs):
    """Load a pickle (path, bytes or binary file) through the allow-list; stubs resolved."""
    name = "<bytes>"
    if isinstance(source, (str, Path)):
        name = str(source)
        data = Path(source).read_bytes()
    elif isinstance(source, (bytes, bytearray)):
        data = bytes(source)
    else:
        name = getattr(source, "name", name)
        data = source.read()
    try:
        obj = RestrictedUnpickler(io.BytesIO(data), source=name, extra=extra, **kwargs).load()
    except InputError:
        raise
    except (
        pickle.UnpicklingError,
        EOFError,
        ValueError,
        TypeError,
        AttributeError,
        IndexError,
        KeyError,
        UnicodeDecodeError,
    ) as exc:
        raise InputError(
            name, None, f"not a readable pickle ({type(exc).__name__}: {exc})"
        ) from exc
    try:
        return resolve(obj, name)
    except ValueError as exc:
        raise InputError(name, None, str(exc)) from exc
