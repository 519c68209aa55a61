"""The 3DGS PLY: our writer against plyfile and our reader, and Gaussians moved into another
space keep their look (positions, shapes and view-dependent colours)."""

import numpy as np
import plyfile
import pytest

from archhead_addon.camera import FLAME_TO_BLENDER
from archhead_addon.export.ply import property_names, read_ply, rows_to_gaussians, write_ply
from archhead_addon.export.transform import sh_rotation, similarity_parts, transform_gaussians
from archhead_addon.io.errors import InputError
from archhead_addon.rotations import axis_angle_to_matrix, quaternion_to_matrix
from archhead_addon.splat.sh import sh_to_rgb_numpy


def _gaussians(n=40, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return {
        "means": rng.normal(size=(n, 3)).astype(np.float32),
        "log_scales": (rng.normal(size=(n, 3)) - 4).astype(np.float32),
        "quats": (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32),
        "opacity_logits": rng.normal(size=n).astype(np.float32),
        "sh": rng.normal(size=(n, 16, 3)).astype(np.float32),
    }


def test_ply_layout_and_round_trip(tmp_path):
    g = _gaussians()
    path = tmp_path / "g.ply"
    write_ply(path, **g)
    ply = plyfile.PlyData.read(str(path))
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == property_names(45)
    assert all(p.val_dtype in ("f4", "<f4", "float32") for p in vertex.properties)
    assert len(vertex.data) == 40 and ply.text is False and ply.byte_order == "<"
    np.testing.assert_array_equal(vertex["x"], g["means"][:, 0])
    np.testing.assert_array_equal(vertex["f_dc_1"], g["sh"][:, 0, 1])
    np.testing.assert_array_equal(vertex["f_rest_0"], g["sh"][:, 1, 0])  # channel-major:
    np.testing.assert_array_equal(vertex["f_rest_15"], g["sh"][:, 1, 1])  # r bands, g, b
    np.testing.assert_array_equal(vertex["f_rest_44"], g["sh"][:, 15, 2])
    np.testing.assert_array_equal(vertex["rot_0"], g["quats"][:, 0])  # w first
    np.testing.assert_array_equal(vertex["opacity"], g["opacity_logits"])
    np.testing.assert_array_equal(vertex["nx"], 0)
    back = rows_to_gaussians(read_ply(path))
    for name, value in g.items():
        np.testing.assert_array_equal(back[name], value)


def test_read_ply_rejects_damaged_files(tmp_path):
    path = tmp_path / "g.ply"
    write_ply(path, **_gaussians())
    data = path.read_bytes()
    path.write_bytes(data[:-10])
    with pytest.raises(InputError, match="truncated"):
        read_ply(path)
    path.write_bytes(data.replace(b"binary_little_endian", b"ascii"))
    with pytest.raises(InputError, match="binary_little_endian"):
        read_ply(path)
    path.write_bytes(b"not a ply")
    with pytest.raises(InputError, match="not a PLY"):
        read_ply(path)


def test_sh_rotation_keeps_the_colour_seen_from_each_direction():
    rng = np.random.default_rng(1)
    rotation = axis_angle_to_matrix(np.array([0.3, -1.1, 0.7]))
    coeffs = rng.normal(size=(16, 3))
    turned = sh_rotation(rotation, 3) @ coeffs
    dirs = rng.normal(size=(200, 3))
    np.testing.assert_allclose(
        sh_to_rgb_numpy(3, dirs @ rotation.T, turned[None]),
        sh_to_rgb_numpy(3, dirs, coeffs[None]),
        atol=1e-9,
    )


def test_transform_gaussians_into_blender_world():
    g = _gaussians()
    matrix = FLAME_TO_BLENDER.copy()
    matrix[:3, :3] *= 2.0
    matrix[:3, 3] = [0.1, -0.2, 0.3]
    means, log_scales, quats, sh = transform_gaussians(
        matrix, g["means"], g["log_scales"], g["quats"], g["sh"]
    )
    np.testing.assert_allclose(means, g["means"] @ matrix[:3, :3].T + matrix[:3, 3], atol=1e-5)
    np.testing.assert_allclose(log_scales, g["log_scales"] + np.log(2.0), atol=1e-6)
    # the covariance turns with the space: R_new = R_space R_old
    np.testing.assert_allclose(
        quaternion_to_matrix(quats.astype(np.float64)),
        FLAME_TO_BLENDER[:3, :3] @ quaternion_to_matrix(g["quats"].astype(np.float64)),
        atol=1e-5,
    )
    # the colour seen from a camera at c equals the one seen from its image in the new space
    camera = np.array([0.2, 0.1, 3.0])
    moved_camera = matrix[:3, :3] @ camera + matrix[:3, 3]
    np.testing.assert_allclose(
        sh_to_rgb_numpy(3, means - moved_camera, sh),
        sh_to_rgb_numpy(3, g["means"] - camera, g["sh"]),
        atol=1e-4,
    )
    with pytest.raises(ValueError, match="unevenly"):
        similarity_parts(np.diag([1.0, 2.0, 1.0, 1.0]))


def test_read_ply_refuses_what_no_splat_file_holds(tmp_path):
    """A header count or property list that disagrees with the body, a header line that is
    not PLY, quaternions no float32 renderer can normalise (fuzz corpus cases)."""
    path = tmp_path / "g.ply"
    g = _gaussians(n=20)
    write_ply(path, **g)
    data = path.read_bytes()
    for old, new in (
        (b"element vertex 20", b"element vertex 19"),
        (b"element vertex 20", b"element vertex 0"),
        (b"property float nx\n", b""),
    ):
        path.write_bytes(data.replace(old, new))
        with pytest.raises(InputError, match="key 'element vertex': .* the header's count or"):
            read_ply(path)
    path.write_bytes(data + bytes(100))
    with pytest.raises(InputError, match="disagree with the body"):
        read_ply(path)
    path.write_bytes(data.replace(b"property float nx", b"property\0\0\0 float nx"))
    with pytest.raises(InputError, match="key 'header': bytes that are not text"):
        read_ply(path)
    path.write_bytes(data.replace(b"property float nx", b"propertee float nx"))
    with pytest.raises(InputError, match="key 'header': unknown line 'propertee float nx'"):
        read_ply(path)
    for scale in (1e-30, 1e30):
        write_ply(path, **{**g, "quats": g["quats"] * np.float32(scale)})
        with pytest.raises(InputError, match="key 'rot_0': quaternion of norm .* at vertex"):
            rows_to_gaussians(read_ply(path), path)


def test_read_ply_flushes_subnormal_values_with_a_warning(tmp_path):
    from archhead_addon.io.errors import InputWarning

    g = _gaussians(n=20)
    g["sh"][3, 2, 1] = np.float32(2.4e-43)
    write_ply(tmp_path / "g.ply", **g)
    with pytest.warns(InputWarning, match="key 'f_rest_16': 1 subnormal float32"):
        back = rows_to_gaussians(read_ply(tmp_path / "g.ply"))
    assert back["sh"][3, 2, 1] == 0
