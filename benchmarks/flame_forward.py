"""The numpy FLAME forward pass (`flame/lbs.py`): one frame in float32, as each head of a
crowd decodes it, and a 300-frame batch in float64, as tracking and training load a
sequence; its two joint products as einsum (before 2026-11-29) against the matrix products
it takes now, and the expression's product with a column slice of the (3V, S+E) blend
shapes (the layout before) against whole rows of the (S+E, 3V) ones it keeps now, in one
process on one BLAS thread. The built-in head; prints the minimum of `--repeats` runs of
each.

    python benchmarks/flame_forward.py [--repeats 50]
"""

from __future__ import annotations

import argparse
from functools import partial

import numpy as np

from archhead_addon.flame.lbs import forward_full, model_arrays
from archhead_addon.flame.model import load_model
from archhead_addon.threads import one_blas_thread
from archhead_addon.timing import time_calls

F32 = np.float32


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=50)
    args = p.parse_args(argv)
    model = load_model()  # the built-in head
    rng = np.random.default_rng(0)
    one = {"expr": (0.5 * rng.normal(size=model.n_expr)).astype(F32), "jaw": F32([0.05, 0, 0])}
    batch = {"expr": 0.5 * rng.normal(size=(300, model.n_expr)), "jaw": rng.normal(size=(300, 3))}
    with one_blas_thread():
        rows = [
            ("forward, 1 frame, float32", lambda: forward_full(model, dtype=F32, **one), 1),
            ("forward, 300 frames, float64", lambda: forward_full(model, **batch), 300),
        ]
        for dtype, frames in ((F32, 1), (np.float64, 300)):  # what each is called with
            a = model_arrays(model, dtype)
            v = rng.normal(size=(frames, model.n_verts, 3)).astype(dtype)
            t = rng.normal(size=(frames, 5, 3, 4)).astype(dtype)
            name = f"{frames} frame{'s' * (frames > 1)}, {np.dtype(dtype).name}"
            joints, weights = a["j_regressor"], a["weights"]
            expr = rng.normal(size=(frames, model.n_expr)).astype(dtype)
            rows_e = a["shapedirs"][model.n_shape :]  # (E, 3V)
            columns = np.ascontiguousarray(a["shapedirs"].T)  # (3V, S+E), as before
            rows += [
                (
                    f"expression, column slice, {name}",
                    lambda c=columns, e=expr: e @ c[:, model.n_shape :].T,
                    frames,
                ),
                (f"expression, rows, {name}", partial(np.matmul, expr, rows_e), frames),
                (f"joints, einsum, {name}", partial(np.einsum, "jv,bvc->bjc", joints, v), frames),
                (f"joints, matmul, {name}", partial(np.matmul, joints, v), frames),
                (
                    f"skinning, einsum, {name}",
                    partial(np.einsum, "vj,bjrc->bvrc", weights, t),
                    frames,
                ),
                (
                    f"skinning, matmul, {name}",
                    partial(np.matmul, weights, t.reshape(frames, 5, 12)),
                    frames,
                ),
            ]
        for name, fn, frames in rows:  # a batch's runs a tenth as many
            ms = time_calls(fn, args.repeats // (10 if frames > 1 else 1)).min_ms
            print(f"{name:46s} {ms:9.3f} ms")


if __name__ == "__main__":
    main()
