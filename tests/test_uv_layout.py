import numpy as np
import pytest
from test_uv_sphere_head import U_RANGE, sphere_head

from archhead_addon.io.errors import InputError
from archhead_addon.uv.layout import avatar_mesh, layout_id, read_obj_uvs, xatlas_uvs
from archhead_addon.uv.raster import rasterize


def _write_obj(path, model, faces=None):
    """An obj in FLAME's template style: v, vt, and f with per-corner UV indices."""
    faces = model.faces if faces is None else faces
    lines = [f"v {x} {y} {z}" for x, y, z in model.v_template]
    lines += [f"vt {u!r} {v!r}" for u, v in model.uv]
    lines += [
        "f " + " ".join(f"{a + 1}/{b + 1}" for a, b in zip(f, ft, strict=True))
        for f, ft in zip(faces, model.uv_faces, strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_models_own_uvs_get_a_teeth_island_in_free_space():
    base = sphere_head()
    mesh = avatar_mesh(base)
    n_old = len(base.uv_faces)
    np.testing.assert_array_equal(mesh.uv_faces[:n_old], base.uv_faces)
    teeth_uv = mesh.uv[mesh.uv_faces[n_old:]]
    assert len(teeth_uv) > 0 and teeth_uv[..., 0].min() > U_RANGE[1]  # right of the head island
    assert mesh.model_id == base.model_id + "+teeth"
    assert layout_id(mesh.uv, mesh.uv_faces) == layout_id(mesh.uv.copy(), mesh.uv_faces.copy())
    assert layout_id(mesh.uv + 1e-9, mesh.uv_faces) != layout_id(mesh.uv, mesh.uv_faces)


def test_template_obj_supplies_the_uvs(tmp_path):
    base = sphere_head()
    obj = _write_obj(tmp_path / "head_template_mesh.obj", base)
    uv, ft = read_obj_uvs(obj, base.faces)
    np.testing.assert_array_equal(ft, base.uv_faces)
    np.testing.assert_array_equal(uv, base.uv)
    without = sphere_head(with_uv=False)
    mesh = avatar_mesh(without, uv_obj=obj)
    expected = avatar_mesh(base)
    np.testing.assert_array_equal(mesh.uv, expected.uv)
    np.testing.assert_array_equal(mesh.uv_faces, expected.uv_faces)


def test_template_obj_errors_name_the_problem(tmp_path):
    base = sphere_head()
    with pytest.raises(InputError, match="not found"):
        read_obj_uvs(tmp_path / "missing.obj", base.faces)
    other = _write_obj(tmp_path / "other.obj", base, faces=base.faces[:, ::-1])
    with pytest.raises(InputError, match="not the model's") as err:
        read_obj_uvs(other, base.faces)
    assert err.value.key == "f"
    no_uv = tmp_path / "no_uv.obj"
    no_uv.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="UV indices") as err:
        read_obj_uvs(no_uv, np.array([[0, 1, 2]]))
    assert err.value.key == "line 5"


@pytest.fixture(scope="module")
def xatlas_mesh(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    return avatar_mesh(sphere_head(with_uv=False), cache=cache), cache


def test_xatlas_layout_covers_the_mesh_with_teeth_and_is_cached(xatlas_mesh):
    mesh, cache = xatlas_mesh
    assert mesh.uv_faces.shape == mesh.faces.shape and mesh.extras["teeth"]
    assert mesh.uv.min() >= 0 and mesh.uv.max() <= 1
    tri = mesh.uv[mesh.uv_faces]
    area = 0.5 * np.abs(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    assert (area > 0).all()
    # charts do not overlap: the texel count matches the covered area
    count = rasterize(mesh.uv, mesh.uv_faces, 256).count
    assert abs(count - area.sum() * 256**2) < 0.05 * count
    files = list(cache.glob("uv-xatlas-*.npz"))
    assert len(files) == 1
    uv, ft = xatlas_uvs(mesh.v_template, mesh.faces, cache)  # from the cache
    np.testing.assert_array_equal(uv, mesh.uv)
    np.testing.assert_array_equal(ft, mesh.uv_faces)


def test_xatlas_layout_is_deterministic_and_survives_a_corrupt_cache(xatlas_mesh, tmp_path):
    mesh, _ = xatlas_mesh
    uv, ft = xatlas_uvs(mesh.v_template, mesh.faces, tmp_path)  # computed afresh
    assert layout_id(uv, ft) == layout_id(mesh.uv, mesh.uv_faces)
    (cached,) = tmp_path.glob("uv-xatlas-*.npz")
    cached.write_bytes(cached.read_bytes()[:100])
    with pytest.warns(UserWarning, match="unreadable UV cache"):
        uv2, _ = xatlas_uvs(mesh.v_template, mesh.faces, tmp_path)
    np.testing.assert_array_equal(uv2, uv)
    with np.load(cached, allow_pickle=False) as z:  # rewritten whole
        np.testing.assert_array_equal(z["uv"], uv)
