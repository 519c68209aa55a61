"""The numpy side of the avatar in Blender: codes back from the rig's channels, decode caches,
frame selection, checkpoint-against-head checks and point attributes (no Blender needed)."""

from dataclasses import replace

import numpy as np
import pytest

from archhead_addon.avatar.checkpoint_format import AvatarCheckpoint
from archhead_addon.avatar.compat import HeadFacts, check_head
from archhead_addon.avatar.config import AvatarConfig
from archhead_addon.avatar.decode_cache import DiskCache, MemoryCache, frame_key
from archhead_addon.avatar.frame_selection import (
    contiguous_runs,
    frames_to_decode,
    held_frame,
    parse_frames,
)
from archhead_addon.avatar.gaussians import SH_C0, Gaussians
from archhead_addon.avatar.point_attributes import point_attributes
from archhead_addon.avatar.scene_codes import codes_from_rig, expression_joint_dirs
from archhead_addon.flame import load_model
from archhead_addon.flame.teeth import add_teeth
from archhead_addon.rig import rig_animation
from archhead_addon.rotations import quaternion_to_matrix
from archhead_addon.sequences.demo import demo_sequence
from archhead_addon.splat.colour_space import srgb_to_linear
from archhead_addon.splat.frame import MIN_OPACITY, SplatFrame


@pytest.fixture(scope="module")
def model():
    return add_teeth(load_model())


def test_codes_from_rig_invert_the_import(model):
    """The import's bone channels and shape-key values give back the tracked codes,
    translation included (the expression's root-joint shift taken out again)."""
    rng = np.random.default_rng(3)
    seq = demo_sequence(frames=5)
    seq = replace(
        seq,
        translation=rng.normal(scale=0.05, size=(5, 3)),
        rotation=rng.normal(scale=0.4, size=(5, 3)),
    )
    seq = seq.fit_to_model(model)
    rig = rig_animation(model, seq)
    dirs = expression_joint_dirs(model, model.n_expr)
    assert np.abs(dirs[: rig.expr.shape[1], 0]).max() > 1e-5  # expressions do move the root
    for t in range(len(seq)):
        codes = codes_from_rig(
            quaternion_to_matrix(rig.bone_quats[t]), rig.bone_locs[t, 0], rig.expr[t], dirs
        )
        for name in ("rotation", "neck", "jaw", "eyes", "translation"):
            np.testing.assert_allclose(getattr(codes, name), getattr(seq, name)[t], atol=1e-9)
        np.testing.assert_allclose(codes.expr, seq.expr[t, : rig.expr.shape[1]])


def _gaussians(n, rng, opacity_logits=None):
    return Gaussians(
        means=rng.normal(size=(n, 3)),
        log_scales=rng.normal(size=(n, 3)) - 5,
        quats=np.tile([1.0, 0, 0, 0], (n, 1)),
        opacity_logits=rng.normal(size=n) if opacity_logits is None else opacity_logits,
        sh=rng.normal(size=(n, 16, 3)),
        offsets=np.zeros((n, 3)),
        uv_texel=np.arange(n),
        resolution=64,
    )


def test_splat_frame_leaves_out_invisible_gaussians():
    rng = np.random.default_rng(0)
    logit = np.log(MIN_OPACITY / (1 - MIN_OPACITY))
    frame = SplatFrame.from_gaussians(
        _gaussians(4, rng, np.array([logit - 1e-3, logit + 1e-3, 5.0, -20.0]))
    )
    assert len(frame) == 2 and frame.opacity_logits.dtype == np.float32
    assert frame.resolution == 64 and frame.sh.shape == (2, 16, 3)


def test_memory_cache_drops_least_recently_used_by_bytes():
    rng = np.random.default_rng(1)
    frames = {k: SplatFrame.from_gaussians(_gaussians(100, rng, np.full(100, 3.0))) for k in "abc"}
    cache = MemoryCache(max_bytes=2 * frames["a"].nbytes)
    cache.put("a", frames["a"])
    cache.put("b", frames["b"])
    assert cache.get("a") is frames["a"]  # a is now the most recent
    cache.put("c", frames["c"])
    assert "b" not in cache and "a" in cache and "c" in cache
    assert cache.nbytes == 2 * frames["a"].nbytes
    cache.resize(frames["a"].nbytes)  # a smaller budget evicts at once, the oldest first
    assert "a" not in cache and "c" in cache and cache.nbytes == frames["c"].nbytes


def test_disk_cache_round_trip_and_damaged_files(tmp_path):
    rng = np.random.default_rng(2)
    frame = SplatFrame.from_gaussians(_gaussians(50, rng, np.full(50, 1.0)))
    cache = DiskCache(tmp_path / "cache")
    cache.put("k1", frame)
    back = cache.get("k1")
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        np.testing.assert_array_equal(getattr(back, name), getattr(frame, name))
    assert back.resolution == frame.resolution
    assert cache.get("absent") is None
    cache.path("k1").write_bytes(cache.path("k1").read_bytes()[:100])  # a torn copy
    assert cache.get("k1") is None
    assert not list((tmp_path / "cache").glob(".*tmp"))  # atomic writes leave no temp files


def test_frame_key_names_avatar_codes_and_lod():
    keys = {
        frame_key("avatar", "codes", 0.5),
        frame_key("avatar", "codes", 0.25),
        frame_key("avatar", "other", 0.5),
        frame_key("other", "codes", 0.5),
    }
    assert len(keys) == 4 and frame_key("avatar", "codes", 0.5) in keys


def test_frame_selection():
    assert parse_frames("1-5") == [1, 2, 3, 4, 5]
    assert parse_frames("1-10:4, 7,3") == [1, 3, 5, 7, 9]
    for bad in ("", "5-1", "a-b", "1-3:0"):
        with pytest.raises(ValueError):
            parse_frames(bad)
    assert frames_to_decode("ALL", 3, 6) == [3, 4, 5, 6]
    assert frames_to_decode("STRIDE", 1, 10, stride=4) == [1, 5, 9]
    assert frames_to_decode("KEYED", 2, 20, keyed=[0.0, 5.0, 9.0, 25.0]) == [2, 5, 9]
    assert held_frame([2, 5, 9], 7) == 5 and held_frame([2, 5, 9], 1) == 2
    assert held_frame([], 3) is None
    assert contiguous_runs([5, 1, 2, 3, 7, 8]) == [(1, 3), (5, 5), (7, 8)]


def _checkpoint(model_id="m", n_faces=4, n_expr=10):
    uv = np.random.default_rng(0).random((6, 2))
    faces = np.arange(3 * n_faces).reshape(n_faces, 3) % 6
    return AvatarCheckpoint(
        config=AvatarConfig(n_expr=n_expr),
        model_id=model_id,
        uv=uv,
        uv_faces=faces,
        identity_shape=np.zeros(5),
        params={},
    )


def test_check_head_names_what_does_not_fit():
    ckpt = _checkpoint()
    loops = ckpt.uv[ckpt.uv_faces].reshape(-1, 2)
    good = HeadFacts(model_id="m+teeth", n_faces=4, identity=np.zeros(5), n_expr=10, loop_uvs=loops)
    assert check_head(ckpt, good, "m").errors == []
    assert check_head(ckpt, good, "m").warnings == []
    wrong = check_head(ckpt, replace(good, model_id="flame2023+teeth"), "m").errors
    assert any("'m'" in e and "'flame2023'" in e for e in wrong)
    assert any("preferences" in e for e in check_head(ckpt, good, "other").errors)
    assert any("faces" in e for e in check_head(ckpt, replace(good, n_faces=5), "m").errors)
    moved = check_head(ckpt, replace(good, loop_uvs=loops + 0.01), "m").errors
    assert any(ckpt.uv_layout_id in e for e in moved)
    notes = check_head(ckpt, replace(good, identity=np.ones(5), n_expr=12), "m").warnings
    assert len(notes) == 2 and "identity" in notes[0] and "12" in notes[1]


def test_point_attributes():
    rng = np.random.default_rng(4)
    frame = SplatFrame.from_gaussians(_gaussians(20, rng, np.linspace(-3, 3, 20)))
    attrs = point_attributes(frame, colour_space="display")
    np.testing.assert_allclose(attrs["scale"], np.exp(frame.log_scales), rtol=1e-6)
    np.testing.assert_allclose(attrs["opacity"], 1 / (1 + np.exp(-frame.opacity_logits)), rtol=1e-6)
    dc = np.maximum(0.5 + SH_C0 * frame.sh[:, 0], 0)
    np.testing.assert_allclose(attrs["colour"][:, :3], srgb_to_linear(dc), rtol=1e-5)
    assert "colour_view" not in attrs and np.all(attrs["colour"][:, 3] == 1)
    # a linear avatar's colours are Blender's already
    np.testing.assert_allclose(point_attributes(frame)["colour"][:, :3], dc, rtol=1e-6)
    centre = np.array([0.0, 0.0, 5.0])
    seen = point_attributes(frame, view_from=centre, colour_space="display")["colour_view"]
    # with only the DC band the view colour is the DC colour
    frame.sh[:, 1:] = 0
    flat = point_attributes(frame, view_from=centre, colour_space="display")["colour_view"]
    np.testing.assert_allclose(flat, attrs["colour"], atol=1e-6)
    assert np.abs(seen - flat).max() > 1e-3
    # one coefficient: no view colour to compute
    assert "colour_view" not in point_attributes(replace(frame, sh=frame.sh[:, :1]), centre)
    assert srgb_to_linear(np.array([0.0, 0.04045, 1.0, 2.0])).tolist() == pytest.approx(
        [0.0, 0.04045 / 12.92, 1.0, 1.0]
    )
