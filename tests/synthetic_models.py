"""Small random FLAME-format models for tests that must not depend on the built-in model."""

from __future__ import annotations

import numpy as np

from archhead_addon.flame.model import FlameModel, model_from_arrays


def random_model_arrays(n_verts=60, n_shape=8, n_expr=6, seed=0) -> dict:
    """A valid FLAME-format dict: a noisy sphere with FLAME's joint layout and random bases."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n_verts, 3))
    v = 0.1 * v / np.linalg.norm(v, axis=1, keepdims=True)
    faces = np.stack(
        [np.arange(n_verts - 2), np.arange(1, n_verts - 1), np.arange(2, n_verts)], axis=1
    )
    weights = rng.random((n_verts, 5)) ** 3
    weights /= weights.sum(1, keepdims=True)
    jreg = rng.random((5, n_verts))
    jreg /= jreg.sum(1, keepdims=True)
    kintree = np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64)
    return {
        "v_template": v,
        "f": faces.astype(np.int64),
        "shapedirs": 0.01 * rng.normal(size=(n_verts, 3, n_shape + n_expr)),
        "posedirs": 0.01 * rng.normal(size=(n_verts, 3, 36)),
        "J_regressor": jreg,
        "weights": weights,
        "kintree_table": kintree,
        "n_shape": np.int64(n_shape),
    }


def random_model(**kwargs) -> FlameModel:
    return model_from_arrays(random_model_arrays(**kwargs), source="random")


def random_codes(model: FlameModel, batch: int, scale: float = 1.0, seed: int = 1) -> dict:
    rng = np.random.default_rng(seed)
    return {
        "shape": scale * rng.normal(size=(batch, model.n_shape)),
        "expr": scale * rng.normal(size=(batch, model.n_expr)),
        "rotation": scale * rng.normal(size=(batch, 3)) * 0.5,
        "neck": scale * rng.normal(size=(batch, 3)) * 0.5,
        "jaw": scale * rng.normal(size=(batch, 3)) * 0.5,
        "eyes": scale * rng.normal(size=(batch, 6)) * 0.5,
        "translation": rng.normal(size=(batch, 3)) * 0.1,
    }
