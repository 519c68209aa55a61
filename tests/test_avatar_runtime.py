"""The numpy runtime against the torch model, its caches, its fp16 path, and no torch import."""

import functools
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest
import torch
from test_avatar_model import ATTRS, frame_codes, make_avatar
from test_uv_sphere_head import sphere_head

from archhead_addon.avatar.checkpoint import save_avatar
from archhead_addon.avatar.checkpoint_format import read_checkpoint
from archhead_addon.avatar.config import ablation
from archhead_addon.avatar.runtime import AvatarRuntime, decode_batch
from archhead_addon.threads import default_threads, machine_cores


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


def test_threads_decode_the_same_gaussians(saved):
    """Chunks of texels decoded on three threads give the single-threaded decode, up to
    BLAS round-off."""
    _, path, head = saved
    serial = AvatarRuntime.load(path, flame=head, threads=1)
    assert AvatarRuntime.load(path, flame=head).threads == default_threads()  # 0: the default
    threaded = AvatarRuntime.load(path, flame=head)
    threaded.threads = 3  # more than this machine may have: the path runs all the same
    for lod in (0.0, 1.0):
        codes = frame_codes(seed=7)
        want, got = serial.decode(lod, **codes), threaded.decode(lod, **codes)
        for name in ATTRS:
            np.testing.assert_allclose(getattr(got, name), getattr(want, name), atol=1e-5)


def test_a_batch_of_decodes_on_threads_gives_each_decode_alone(saved):
    """decode_batch: several heads' frames decoded at once on threads of their own (a crowd)
    give what each decodes alone, in the jobs' order; a failing job leaves its exception in
    its place and the others still decode; a level that several ask for is built once."""
    _, path, head = saved
    alone = AvatarRuntime.load(path, flame=head, threads=1)
    shared = AvatarRuntime.load(path, flame=head)
    lods = [1.0, 0.0, 0.6, 1.0, 0.3, 1.0]  # four levels, one of them asked for three times
    codes = [frame_codes(seed=s) for s in range(len(lods))]
    threads = {}  # job -> the thread it ran on

    def job(i, lod, **codes):
        threads[i] = threading.current_thread().name
        return shared.decode(lod, **codes)

    jobs = [
        functools.partial(job, i, lod, **c)
        for i, (lod, c) in enumerate(zip(lods, codes, strict=True))
    ]
    jobs.insert(2, functools.partial(job, -1, 0.0, jaw=[np.nan, 0, 0]))  # fails past its level
    # job 1 outweighs an equal share of all: it decodes first, alone on every core
    weights = [1.0, 20.0] + [1.0] * (len(jobs) - 2)
    results = decode_batch(jobs, weights, threads=2)
    if machine_cores() > 1:  # (one core: one after another, in this thread)
        assert threads.pop(1) == threading.current_thread().name
        assert all(name.startswith("archhead-decode-batch") for name in threads.values())
    assert isinstance(results.pop(2), ValueError)
    for lod, c, got in zip(lods, codes, results, strict=True):
        want = alone.decode(lod, **c)
        assert got.resolution == want.resolution
        for name in ATTRS:
            np.testing.assert_allclose(getattr(got, name), getattr(want, name), atol=1e-5)
    assert (shared.level.misses, shared.level.hits) == (4, len(jobs) - 4)


def test_heads_posed_together_decode_as_each_alone(saved):
    """`pose`: several frames' FLAME in one batched pass (a crowd's heads) gives each
    decode what posing it alone gives, up to float32 round-off, whatever codes each has:
    expressions of other widths or none; a code with NaN fails the pass, naming it."""
    _, path, head = saved
    runtime = AvatarRuntime.load(path, flame=head, threads=1)
    codes = [frame_codes(seed=s) for s in range(3)]
    codes[1]["expr"] = codes[1]["expr"][:7]
    codes.append({})  # the neutral face
    posing = ("expr", "jaw", "neck", "eyes")
    posed = runtime.pose([{k: c[k] for k in posing if k in c} for c in codes])
    assert len(posed) == len(codes)
    for c, p in zip(codes, posed, strict=True):
        want, got = runtime.decode(0.4, **c), runtime.decode(0.4, posed=p, **c)
        for name in ATTRS:  # as against torch: the PE's top octave scales a position's
            # float32 round-off by 2^11
            assert np.abs(getattr(got, name) - getattr(want, name)).max() <= 1e-4, name
    with pytest.raises(ValueError, match="jaw"):
        runtime.pose([codes[0], {"jaw": [np.nan, 0, 0]}])
    assert runtime.pose([]) == []


def test_runtime_never_imports_torch(saved):
    _, path, head = saved
    script = textwrap.dedent(f"""
        import sys
        from archhead_addon.avatar.runtime import AvatarRuntime, decode_batch
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
    runtime = AvatarRuntime.load(path, flame=head)
    runtime.decode(0.8)
    runtime.decode(0.801)  # the same S = 102
    assert (runtime.level.hits, runtime.level.misses) == (1, 1)
    level = runtime.level(102, "fp32")
    n, width = len(level["texel"]), runtime.config.fused_width
    assert level["first"].shape == (width, n) and level["first"].dtype == np.float32
    two = runtime.level.nbytes + 1  # room for this level and a smaller one, not three
    runtime.level.max_bytes = 2 * two
    for lod in (0.9, 1.0, 0.8):  # evicts the least recently used past the budget
        runtime.decode(lod)
    assert len(runtime.level) == 2 and runtime.level.nbytes <= 2 * two


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


def test_fewer_sh_bands_and_culling_decode_subsets_of_the_full_frame(tmp_path):
    """`sh_degree` keeps the first coefficients of the full decode; a view keeps exactly the
    Gaussians of its texels, unchanged, and drops those that cannot reach the camera."""
    from archhead_addon.avatar.config import AvatarConfig
    from archhead_addon.avatar.culling import ViewFrustum

    config = AvatarConfig(n_expr=sphere_head().n_expr, sh_degree=3)
    save_avatar(tmp_path / "sh3.npz", make_avatar(config))
    np.savez(tmp_path / "head.npz", **sphere_head().to_arrays())
    runtime = AvatarRuntime.load(tmp_path / "sh3.npz", flame=tmp_path / "head.npz")
    codes = frame_codes(seed=3)
    full = runtime.decode(0.0, **codes)
    dc = runtime.decode(0.0, sh_degree=0, **codes)
    assert full.sh.shape[1] == 16 and dc.sh.shape[1] == 1
    np.testing.assert_allclose(dc.sh, full.sh[:, :1], atol=1e-5)  # BLAS round-off
    # a camera 0.5 m in front of the head, looking at it; K wide enough for all of it
    centre = full.means.mean(0).astype(np.float64)
    w2c = np.diag([1.0, -1.0, -1.0, 1.0])
    w2c[:3, 3] = -w2c[:3, :3] @ (centre + [0, 0, 0.5])
    wide_K = [[100, 0, 50], [0, 100, 50], [0, 0, 1]]
    wide = ViewFrustum.from_camera(w2c, wide_K, 100, 100)
    assert len(runtime.decode(0.0, view=wide, **codes)) == len(full)
    # a narrow lens sees the middle of the head only
    narrow = ViewFrustum.from_camera(w2c, [[2000, 0, 50], [0, 2000, 50], [0, 0, 1]], 100, 100)
    part = runtime.decode(0.0, view=narrow, **codes)
    assert 0 < len(part) < 0.8 * len(full)  # random weights: offsets reach far
    index = {t: i for i, t in enumerate(full.uv_texel.tolist())}
    rows = [index[t] for t in part.uv_texel.tolist()]
    for name in ATTRS:
        np.testing.assert_allclose(getattr(part, name), getattr(full, name)[rows], atol=1e-5)
    # what was left out lies beyond the view, even with its reach
    dropped = np.setdiff1d(np.arange(len(full)), rows)
    cam = full.means[dropped] @ w2c[:3, :3].T + w2c[:3, 3]
    outside = np.abs(cam[:, :2]).max(axis=1) / cam[:, 2]
    assert len(dropped) and (outside > 50 / 2000).all()
    # a camera looking away from the head: an empty cloud, never an error (a crowd's far heads)
    away = w2c.copy()
    away[:3, 3] = -away[:3, :3] @ (centre - [0, 0, 0.5])
    nothing = runtime.decode(0.0, view=ViewFrustum.from_camera(away, wide_K, 100, 100), **codes)
    assert len(nothing) == 0 and nothing.sh.shape == (0, 16, 3) and nothing.means.shape == (0, 3)


def test_identity_offset_moves_the_avatar_alike_in_torch_numpy_and_the_checkpoint(tmp_path):
    """A tracking's static offset becomes part of the avatar's identity (avatar/identity.py):
    saved with it, and applied the same way by the torch model and the numpy runtime."""
    head = sphere_head()
    offset = np.zeros((head.n_verts, 3))
    offset[: head.n_verts // 2, 2] = 0.004  # half the head pushed 4 mm forward
    plain = make_avatar(seed=7)
    moved = make_avatar(seed=7)
    moved = type(moved)(
        moved.mesh, moved.identity_shape.numpy(), moved.config, moved.base_model_id, offset
    )
    moved.load_state_dict(plain.state_dict())
    save_avatar(tmp_path / "a.npz", moved)
    runtime = AvatarRuntime.load(tmp_path / "a.npz", flame=head)
    np.testing.assert_allclose(read_checkpoint(tmp_path / "a.npz").identity_offset, offset)
    _assert_agree(moved, runtime, 0.5, frame_codes(seed=8))
    with torch.no_grad():  # FLAME's static offset: added to the template before posing
        verts = moved.flame()[0] - plain.flame()[0]  # the identity is in their templates
        shift = (moved(0.0).means - plain(0.0).means).norm(dim=1)
    np.testing.assert_allclose(verts[: head.n_verts].numpy(), offset, atol=1e-6)
    assert shift.max() > 0.003 and (shift < 1e-6).float().mean() > 0.3  # the other half stays
