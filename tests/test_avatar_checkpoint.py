"""The checkpoint: numpy-readable, round trip through torch, clear errors for bad files."""

import numpy as np
import pytest
import torch
from test_avatar_model import ATTRS, frame_codes, make_avatar
from test_uv_sphere_head import sphere_head

from archhead_addon.avatar.checkpoint import load_avatar, save_avatar
from archhead_addon.avatar.checkpoint_format import FORMAT_VERSION, read_checkpoint
from archhead_addon.avatar.config import parameter_shapes
from archhead_addon.io.errors import InputError
from archhead_addon.uv.layout import layout_id


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    path = tmp_path_factory.mktemp("ckpt") / "avatar.npz"
    avatar = make_avatar(seed=7)
    save_avatar(path, avatar)
    return avatar, path


def _rewrite(src, dst, **changes):
    """Copy a checkpoint with some keys replaced (None deletes the key)."""
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    np.savez(dst, **{k: v for k, v in arrays.items() if v is not None})
    return dst


def test_numpy_alone_reads_everything(saved):
    avatar, path = saved
    with np.load(path, allow_pickle=False) as z:
        assert str(z["format"]) == "archhead-avatar" and int(z["format_version"]) == 1
        assert str(z["model_id"]) == sphere_head().model_id
        assert str(z["uv_layout_id"]) == layout_id(avatar.mesh.uv, avatar.mesh.uv_faces)
        for name, shape in parameter_shapes(avatar.config).items():
            assert z[f"param/{name}"].shape == shape and z[f"param/{name}"].dtype == np.float32
        np.testing.assert_array_equal(z["identity_shape"], avatar.identity_shape.numpy())
    assert not list(path.parent.glob(".*tmp"))  # the atomic write left nothing behind


def test_torch_round_trip_reproduces_the_avatar(saved):
    avatar, path = saved
    loaded = load_avatar(path, flame=sphere_head())
    assert loaded.config == avatar.config
    codes = frame_codes(seed=8)
    with torch.no_grad():
        a, b = avatar(0.9, **codes), loaded(0.9, **codes)
    for name in ATTRS:
        torch.testing.assert_close(getattr(a, name), getattr(b, name), atol=0, rtol=0)


def test_other_version_or_foreign_npz_is_refused(saved, tmp_path):
    _, path = saved
    newer = _rewrite(path, tmp_path / "v2.npz", format_version=np.int64(FORMAT_VERSION + 1))
    with pytest.raises(InputError, match="format version 2; this ArchHead reads version 1") as e:
        read_checkpoint(newer)
    assert e.value.key == "format_version" and e.value.path == newer
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, weights=np.zeros(3))
    with pytest.raises(InputError, match="not an ArchHead avatar checkpoint"):
        read_checkpoint(foreign)
    with pytest.raises(InputError, match="not found"):
        read_checkpoint(tmp_path / "missing.npz")


def test_truncated_or_damaged_files_give_a_clear_error(saved, tmp_path):
    _, path = saved
    data = path.read_bytes()
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="not a readable checkpoint") as e:
        read_checkpoint(truncated)
    assert e.value.path == truncated
    # flip bytes inside the largest member's data: its CRC no longer matches
    damaged = tmp_path / "damaged.npz"
    middle = bytearray(data)
    at = data.index(b"param/features.256") + 4096
    middle[at : at + 16] = bytes(16)
    damaged.write_bytes(bytes(middle))
    with pytest.raises(InputError, match="corrupt") as e:
        read_checkpoint(damaged)
    assert e.value.key == "param/features.256"


def test_missing_misshapen_or_non_finite_weights_name_the_key(saved, tmp_path):
    _, path = saved
    key = "param/decoder.first.weight"
    with np.load(path, allow_pickle=False) as z:
        weight = z[key]
    cases = {"missing": None, "shape": weight[:, :-1], "NaN or Inf": np.full_like(weight, np.nan)}
    for problem, value in cases.items():
        bad = _rewrite(path, tmp_path / "bad.npz", **{key: value})
        with pytest.raises(InputError, match=problem) as e:
            read_checkpoint(bad)
        assert e.value.key == key
    bad = _rewrite(path, tmp_path / "bad.npz", config=np.str_('{"levels": [256], "tau": -1}'))
    with pytest.raises(InputError, match="invalid") as e:
        read_checkpoint(bad)
    assert e.value.key == "config"
    bad = _rewrite(path, tmp_path / "bad.npz", uv_layout_id=np.str_("uv-0000"))
    with pytest.raises(InputError, match="damaged"):
        read_checkpoint(bad)


def test_the_avatar_needs_the_model_it_was_trained_on(saved):
    _, path = saved
    with pytest.raises(InputError, match="trained on") as e:
        load_avatar(path, flame=sphere_head(n_lat=30))
    assert e.value.key == "model_id"
