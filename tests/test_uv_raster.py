import time

import numpy as np
import pytest
import torch
from test_uv_sphere_head import U_RANGE, V_RANGE, sphere_head

from archhead_addon.uv.layout import avatar_mesh
from archhead_addon.uv.raster import UVRaster, face_texel_scale, position_map, rasterize


def _centres(table):
    rows, cols = table.texel // table.size, table.texel % table.size
    return np.stack([(cols + 0.5) / table.size, 1 - (rows + 0.5) / table.size], 1)


@pytest.mark.parametrize("size", [64, 97, 256])
def test_table_covers_exactly_the_texel_centres_inside_the_island(size):
    model = sphere_head()
    table = rasterize(model.uv, model.uv_faces, size)
    centres = (np.arange(size) + 0.5) / size
    n_cols = ((centres >= U_RANGE[0]) & (centres <= U_RANGE[1])).sum()
    n_rows = ((centres >= V_RANGE[0]) & (centres <= V_RANGE[1])).sum()
    assert table.count == n_cols * n_rows  # no texel lost on the shared edges, none outside
    assert (np.diff(table.texel) > 0).all()  # each texel once, ascending
    assert table.valid.sum() == table.count and table.valid.shape == (size, size)
    assert (table.bary >= 0).all() and np.allclose(table.bary.sum(1), 1)
    # the barycentrics reproduce each texel centre in its face
    uv = np.einsum("nk,nkc->nc", table.bary, model.uv[model.uv_faces[table.face]])
    np.testing.assert_allclose(uv, _centres(table), atol=1e-12)


def test_position_map_of_a_flat_mesh_is_the_texel_centre_and_torch_agrees():
    model = sphere_head()
    verts = np.concatenate([model.uv * 0.3, np.full((len(model.uv), 1), 0.05)], 1)
    table = rasterize(model.uv, model.uv_faces, 128)
    vert_idx = model.uv_faces[table.face]
    pos = position_map(verts, vert_idx, table.bary)
    np.testing.assert_allclose(pos[:, :2], 0.3 * _centres(table), atol=1e-12)
    np.testing.assert_allclose(pos[:, 2], 0.05)
    batch = np.stack([verts, 2 * verts])
    pos_t = position_map(
        torch.from_numpy(batch), torch.from_numpy(vert_idx), torch.from_numpy(table.bary)
    )
    np.testing.assert_allclose(pos_t.numpy(), np.stack([pos, 2 * pos]), atol=1e-12)
    scale = face_texel_scale(verts, model.uv_faces, model.uv, model.uv_faces)
    np.testing.assert_allclose(scale, 0.3)  # metres per UV unit of a map scaled by 0.3


def test_counts_fall_with_lod_on_the_avatar_mesh_and_tables_are_cached():
    mesh = avatar_mesh(sphere_head())
    raster = UVRaster(mesh.uv, mesh.uv_faces)
    sizes = [int(np.floor(256 - l * 192 + 0.5)) for l in np.linspace(0, 1, 21)]
    counts = [raster.table(s).count for s in sizes]
    assert all(a > b for a, b in zip(counts, counts[1:], strict=False))
    assert 0.04 < counts[-1] / counts[0] < 0.09  # ~ (64/256)^2 = 6.25 %
    assert raster.table(256) is raster.table(256)


def test_table_for_256_is_fast_on_a_larger_mesh():
    model = sphere_head(n_lat=100, n_lon=100)  # 20,000 faces, twice FLAME's
    start = time.perf_counter()
    table = rasterize(model.uv, model.uv_faces, 256)
    assert time.perf_counter() - start < 0.5
    assert table.count > 30000


def test_degenerate_faces_and_sizes():
    uv = np.array([[0.1, 0.1], [0.9, 0.1], [0.1, 0.9], [0.5, 0.5]])
    faces = np.array([[0, 1, 2], [3, 3, 3], [0, 0, 1]])  # two zero-area triangles
    table = rasterize(uv, faces, 64)
    assert set(table.face.tolist()) == {0}
    with pytest.raises(ValueError, match="positive integer"):
        rasterize(uv, faces, 0)
    with pytest.raises(ValueError, match="positive integer"):
        rasterize(uv, faces, 64.5)
