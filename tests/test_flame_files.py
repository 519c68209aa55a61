"""FLAME model files: official pickle layouts (2020 chumpy, 2023 scipy sparse), npz, bad input."""

import pickle
import sys
import types

import numpy as np
import pytest
from synthetic_models import random_model_arrays

from archhead_addon.flame.model import load_model
from archhead_addon.io.errors import InputError, InputWarning
from archhead_addon.io.safe_pickle import safe_load


class _Foreign:
    """Pickles like an instance of `module.name` with `state` as its __dict__ state."""

    def __init__(self, state):
        self.__dict__.update(state)


def _fake_class(module: str, name: str, monkeypatch):
    """Make `module.name` importable so pickle writes a reference to it, as the real one would."""
    mod = types.ModuleType(module)
    cls = type(name, (_Foreign,), {"__module__": module})
    setattr(mod, name, cls)
    parts = module.split(".")
    for i in range(1, len(parts) + 1):
        monkeypatch.setitem(
            sys.modules,
            ".".join(parts[:i]),
            mod if i == len(parts) else types.ModuleType(".".join(parts[:i])),
        )
    return cls


def _flame2020_pickle(arrays, monkeypatch) -> bytes:
    """FLAME 2020: chumpy Ch objects for some arrays (state dict with 'x'), protocol 2."""
    ch = _fake_class("chumpy.ch", "Ch", monkeypatch)
    jreg = _fake_class("scipy.sparse.csc", "csc_matrix", monkeypatch)
    data = dict(arrays)
    for key in ("shapedirs", "v_template", "posedirs"):
        data[key] = ch({"x": arrays[key], "dterms": ["x"], "_dirty_vars": set(), "_itr": None})
    data["J_regressor"] = jreg(_csc_state(arrays["J_regressor"]))
    data["bs_style"], data["bs_type"] = "lbs", "lrotmin"
    del data["n_shape"]
    return pickle.dumps(data, protocol=2)


def _csc_state(dense):
    rows, cols = np.nonzero(dense.T)  # column-major order of the nonzeros
    indptr = np.searchsorted(rows, np.arange(dense.shape[1] + 1))
    return {
        "_shape": dense.shape,
        "maxprint": 50,
        "indices": cols.astype(np.int32),
        "indptr": indptr.astype(np.int32),
        "data": dense.T[rows, cols],
    }


def _flame2023_pickle(arrays, monkeypatch) -> bytes:
    """FLAME 2023: plain arrays, J_regressor a scipy.sparse._csc.csc_matrix."""
    jreg = _fake_class("scipy.sparse._csc", "csc_matrix", monkeypatch)
    data = {k: v for k, v in arrays.items() if k != "n_shape"}
    data["J_regressor"] = jreg(_csc_state(arrays["J_regressor"]))
    return pickle.dumps(data, protocol=4)


@pytest.fixture
def arrays():
    # 300 + 100 components like the official files, so n_shape defaults to 300
    return random_model_arrays(n_verts=40, n_shape=300, n_expr=100)


@pytest.mark.parametrize("writer", [_flame2020_pickle, _flame2023_pickle])
def test_official_pickle_layouts(tmp_path, arrays, writer, monkeypatch):
    blob = writer(arrays, monkeypatch)
    monkeypatch.undo()  # the reader must not need the fake modules (nor chumpy / scipy)
    path = tmp_path / "generic_model.pkl"
    path.write_bytes(blob)
    model = load_model(path)
    assert (model.n_shape, model.n_expr) == (300, 100)
    for key, value in model.to_arrays().items():
        if key in arrays and key != "kintree_table":
            np.testing.assert_allclose(value, arrays[key], atol=1e-15, err_msg=key)
    assert model.parents.tolist() == [-1, 0, 1, 1, 1]
    assert "chumpy" not in sys.modules and "scipy" not in sys.modules


def test_npz_round_trip(tmp_path, arrays):
    path = tmp_path / "model.npz"
    np.savez(path, **arrays)
    model = load_model(path)
    again = tmp_path / "again.npz"
    np.savez(again, **model.to_arrays())
    model2 = load_model(again)
    for key, value in model.to_arrays().items():
        np.testing.assert_array_equal(value, model2.to_arrays()[key], err_msg=key)


class _Exploit:
    def __reduce__(self):
        import os

        return (os.system, ("touch PWNED_MARKER",))


def test_malicious_pickle_refused_without_running(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"v_template": _Exploit()}))
    with pytest.raises(InputError, match=r"evil\.pkl.*(posix|os)\.system.*not on the allow-list"):
        load_model(path)
    assert not (tmp_path / "PWNED_MARKER").exists()
    for name in ("builtins.eval", "subprocess.Popen", "numpy.load"):
        module, attr = name.rsplit(".", 1)
        payload = b"\x80\x02c" + module.encode() + b"\n" + attr.encode() + b"\nq\x00."
        with pytest.raises(InputError, match="not on the allow-list"):
            safe_load(payload)


@pytest.mark.parametrize(
    "mutate, key, problem",
    [
        (lambda a: a.pop("weights"), "weights", "missing"),
        (lambda a: a.update(posedirs=a["posedirs"][:, :, :30]), "posedirs", "36 pose correctives"),
        (
            lambda a: a.update(J_regressor=a["J_regressor"][:4]),
            "J_regressor",
            r"expected \(5, 40\)",
        ),
        (lambda a: a.update(f=a["f"] + 1000), "f", "indices below 40"),
        (lambda a: a["v_template"].__setitem__((0, 0), np.nan), "v_template", "NaN or Inf"),
        (
            lambda a: a.update(kintree_table=np.array([[4294967295, 0, 3, 1, 1], [0, 1, 2, 3, 4]])),
            "kintree_table",
            "parents must come before",
        ),
    ],
)
def test_bad_model_keys_named(tmp_path, arrays, mutate, key, problem):
    mutate(arrays)
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(InputError, match=rf"bad\.npz: key '{key}': .*{problem}"):
        load_model(path)


@pytest.mark.parametrize(
    "mutate, key, problem",
    [
        (lambda a: a.update(v_template=np.full_like(a["v_template"], -1)), "v_template",
         "every vertex at one point"),
        (lambda a: a.update(shapedirs=a["shapedirs"] + 0.5), "shapedirs",
         "more than the template's whole size"),
        (lambda a: a.update(posedirs=np.full_like(a["posedirs"], 1e6)), "posedirs",
         "per unit coefficient"),
        (lambda a: a.update(weights=a["weights"] + 0.5), "weights", "not in 0..1 summing to 1"),
        (lambda a: a.update(weights=-a["weights"]), "weights", "not in 0..1"),
        (lambda a: a.update(J_regressor=np.full_like(a["J_regressor"], -1)), "J_regressor",
         "row sums to -40, not 1"),
        (lambda a: a.update(f=np.ones_like(a["f"], bool)), "f", "booleans"),
        (lambda a: a.update(shapedirs=a["shapedirs"] > 0), "shapedirs", "booleans"),
    ],
    ids=["template of one point", "shapedirs +0.5", "posedirs 1e6", "weights +0.5",
         "weights negative", "J_regressor -1", "f bool", "shapedirs bool"],
)  # fmt: skip
def test_impossible_rigs_are_refused(tmp_path, arrays, mutate, key, problem):
    """Values of the right type and shape that no FLAME-layout model has (fuzz corpus)."""
    mutate(arrays)
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(InputError, match=rf"bad\.npz: key '{key}': .*{problem}"):
        load_model(path)


def test_corrupt_and_missing_files(tmp_path, arrays):
    path = tmp_path / "model.npz"
    np.savez(path, **arrays)
    cut = tmp_path / "cut.npz"
    cut.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputError, match=r"cut\.npz: not a readable npz"):
        load_model(cut)
    junk = tmp_path / "junk.pkl"
    junk.write_bytes(b"\x00\x01garbage")
    with pytest.raises(InputError, match=r"junk\.pkl: not a readable pickle"):
        load_model(junk)
    with pytest.raises(InputError, match="not found"):
        load_model(tmp_path / "absent.pkl")


def test_model_without_expressions_warns(tmp_path):
    arrays = random_model_arrays(n_shape=8, n_expr=0)
    path = tmp_path / "noexpr.npz"
    np.savez(path, **arrays)
    with pytest.warns(InputWarning, match="no expression components"):
        assert load_model(path).n_expr == 0
