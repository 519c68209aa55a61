"""The numpy runtime against the torch model, its caches, its fp16 path, and no torch import."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch
from test_avatar_model import ATTRS, frame_codes, make_avatar
from test_uv_sphere_head import sphere_head

from archhead_addon.avatar.checkpoint import save_avatar
from archhead_addon.avatar.config import ablation
from archhead_addon.avatar.runtime import AvatarRuntime


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """(torch avatar with random weights, checkpoint path, FLAME model npz path)."""
    folder = tmp_path_factory.mktemp("avatar")
    avatar = make_avatar()
    save_avatar(folder / "avatar.npz", avatar)
    np.savez(folder / "head.npz", **sphere_head().to_arrays())
    return avatar, folder / "avatar.npz", folder / "head.npz"


def _assert_agree(avatar, runtime, lod, codes):
    with torch.no_grad():
        want = avatar(lod, **codes)
    got = runtime.decode(lod, **codes)
    assert got.resolution == want.resolution and len(got) == len(want)
    np.testing.assert_array_equal(got.uv_texel, want.uv_texel.numpy())
    for name in ATTRS:
        a, b = getattr(got, name), getattr(want, name).numpy()
        assert a.dtype == np.float32 and a.shape == b.shape, name
        assert np.abs(a - b).max() <= 1e-4, (name, lod, np.abs(a - b).max())


@pytest.mark.parametrize("lod", [0.0, 0.37, 1.0])
def test_numpy_runtime_matches_torch(saved, lod):
    avatar, path, head = saved
    runtime = AvatarRuntime.load(path, flame=head)
    _assert_agree(avatar, runtime, lod, frame_codes(seed=2))
    _assert_agree(avatar, runtime, lod, {})  # neutral face, all codes absent


@pytest.mark.parametrize("name", ["no_fmap", "fmap64"])
def test_numpy_runtime_matches_torch_for_ablations(tmp_path, name):
    avatar = make_avatar(ablation(name, n_expr=100, head_layers=3), seed=3)
    save_avatar(tmp_path / "a.npz", avatar)
    runtime = AvatarRuntime.load(tmp_path / "a.npz", flame=sphere_head())
    _assert_agree(avatar, runtime, 0.37, frame_codes(seed=4))


@pytest.mark.parametrize("octaves", [0, 6])
def test_numpy_runtime_matches_torch_for_other_pe_octaves(tmp_path, octaves):
    avatar = make_avatar(ablation("full", n_expr=100, pe_freqs=octaves), seed=5)
    assert avatar.decoder.first.in_features == 3 + 6 * octaves + 64 + 20 + 1
    save_avatar(tmp_path / "a.npz", avatar)
    runtime = AvatarRuntime.load(tmp_path / "a.npz", flame=sphere_head())
    assert runtime.config.pe_freqs == octaves
    _assert_agree(avatar, runtime, 0.6, frame_codes(seed=6))


def test_runtime_never_imports_torch(saved):
    _, path, head = saved
    script = textwrap.dedent(f"""
        import sys
        from archhead_addon.avatar.runtime import AvatarRuntime
        g = AvatarRuntime.load({str(path)!r}, flame={str(head)!r}).decode(0.5, jaw=[0.3, 0, 0])
        assert len(g) > 1000
        loaded = sorted(m for m in sys.modules if m == "torch" or m.startswith("torch."))
        print("torch modules:", loaded)
        sys.exit(1 if loaded else 0)
    """)
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_per_resolution_work_is_cached(saved):
    _, path, head = saved
    runtime = AvatarRuntime.load(path, flame=head, max_cached=2)
    runtime.decode(0.8)
    runtime.decode(0.801)  # the same S = 102
    info = runtime.level.cache_info()
    assert (info.hits, info.misses) == (1, 1)
    level = runtime.level(102, "fp32")
    n, width = len(level["texel"]), runtime.config.fused_width
    assert level["first"].shape == (width, n) and level["first"].dtype == np.float32
    for lod in (0.9, 1.0, 0.8):  # evicts the oldest beyond two resolutions
        runtime.decode(lod)
    assert runtime.level.cache_info().currsize == 2


def test_fp16_path_stays_close_and_halves_the_cache(saved):
    _, path, head = saved
    runtime = AvatarRuntime.load(path, flame=head)
    codes = frame_codes(seed=5)
    errors = runtime.precision_error(0.9, **codes)
    assert set(errors) == {"means", "log_scales", "quats", "opacity_logits", "sh"}
    assert errors["means"] < 1e-4
    assert 0 < max(errors.values()) < 2e-2
    half = runtime.decode(0.9, precision="fp16", **codes)
    assert all(np.isfinite(getattr(half, a)).all() for a in ATTRS)
    size = runtime.resolution(0.9)
    assert runtime.level(size, "fp16")["first"].dtype == np.float16
    with pytest.raises(ValueError, match="precision"):
        runtime.decode(0.9, precision="int8")
