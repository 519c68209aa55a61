"""The Sequence class, the canonical npz, format detection and the convert command."""

import subprocess
import sys

import numpy as np
import pytest
from synthetic_models import random_model
from test_sequences_formats import write_vhap_export

from archhead_addon.__main__ import main
from archhead_addon.io.errors import InputError, InputWarning
from archhead_addon.sequences import (
    FORMAT_VERSION,
    Sequence,
    detect_format,
    read_canonical,
    read_sequence,
    write_canonical,
)


def in_front(translation: np.ndarray) -> np.ndarray:
    """`translation` (T,3) with z folded to 0.5 m or more: the head in front of an identity
    camera (OpenCV: z forward), as validation requires of a sequence with cameras."""
    translation = np.array(translation, dtype=np.float64)
    translation[:, 2] = 0.5 + np.abs(translation[:, 2])
    return translation


def make_sequence(n=5, n_shape=10, n_expr=7, camera=True, seed=0, **changes) -> Sequence:
    rng = np.random.default_rng(seed)
    fields = {
        "shape": rng.normal(size=(n, n_shape)),
        "expr": rng.normal(size=(n, n_expr)),
        "jaw": rng.normal(size=(n, 3)),
        "neck": rng.normal(size=(n, 3)),
        "eyes": rng.normal(size=(n, 6)),
        "rotation": rng.normal(size=(n, 3)),
        "translation": in_front(rng.normal(size=(n, 3))),
        "fps": 30.0,
        "frame_ids": np.arange(n) * 2 + 7,
        "source": "memory.npz",
        "format": "test",
        "static_offset": 0.01 * rng.normal(size=(12, 3)),
        "eyelids": rng.uniform(size=(n, 2)),
    }
    if camera:
        fields.update(
            K=np.repeat(np.array([[[900.0, 0, 256], [0, 900, 250], [0, 0, 1]]]), n, 0),
            w2c=np.repeat(np.eye(4)[None], n, axis=0),
            image_size=(500, 512),
        )
    fields.update(changes)
    return Sequence(**fields)


def test_fields_are_float64_and_len():
    seq = make_sequence(shape=np.ones((5, 10), np.float32))
    assert seq.shape.dtype == np.float64 and seq.frame_ids.dtype == np.int64
    assert len(seq) == 5 and seq.validate() is seq


def test_validate_names_key_and_frame():
    expr = np.zeros((5, 7))
    expr[3, 2] = np.nan
    with pytest.raises(
        InputError,
        match=r"memory.npz: key 'expr': NaN or Inf at frame index 3 "
        r"\(frame id 13\)",
    ):
        make_sequence(expr=expr).validate()
    w2c = np.repeat(np.eye(4)[None], 5, axis=0)
    w2c[1, 0, 3] = np.inf
    with pytest.raises(InputError, match="key 'w2c': NaN or Inf at frame index 1"):
        make_sequence(w2c=w2c).validate()
    offset = np.zeros((12, 3))
    offset[9] = np.nan
    with pytest.raises(InputError, match="key 'static_offset': NaN or Inf at vertex index 9"):
        make_sequence(static_offset=offset).validate()
    with pytest.raises(InputError, match=r"key 'eyes': expected shape \(5, 6\), found \(5, 3\)"):
        make_sequence(eyes=np.zeros((5, 3))).validate()
    with pytest.raises(InputError, match="key 'jaw': expected shape"):
        make_sequence(jaw=np.zeros((4, 3))).validate()
    with pytest.raises(InputError, match="key 'frame_ids': frame ids are not strictly"):
        make_sequence(frame_ids=[0, 1, 1, 2, 3]).validate()
    with pytest.raises(InputError, match="key 'fps'"):
        make_sequence(fps=0).validate()
    with pytest.raises(InputError, match="key 'w2c': intrinsics and extrinsics"):
        make_sequence(w2c=None).validate()


def test_empty_sequence_is_an_error():
    with pytest.raises(InputError, match="key 'expr': the sequence has no frames"):
        make_sequence(n=0, camera=False, static_offset=None).validate()


def test_fit_to_model_pads_and_truncates_with_warnings():
    model = random_model(n_verts=20, n_shape=8, n_expr=6)
    seq = make_sequence(n_shape=300, n_expr=3)
    with pytest.warns(InputWarning) as caught:
        fitted = seq.fit_to_model(model)
    messages = [str(w.message) for w in caught]
    assert any(
        "key 'shape': 300 identity shape coefficients, the model has 8: truncated, the "
        "last 292 dropped" in m
        for m in messages
    )
    assert any(
        "key 'expr': 3 expression coefficients, the model has 6: padded with 3 zeros" in m
        for m in messages
    )
    assert any(
        "key 'static_offset': 12 vertex offsets, the model has 20 vertices: padded with "
        "8 zero rows" in m
        for m in messages
    )
    np.testing.assert_array_equal(fitted.shape, seq.shape[:, :8])
    np.testing.assert_array_equal(fitted.expr[:, :3], seq.expr)
    np.testing.assert_array_equal(fitted.expr[:, 3:], 0.0)
    np.testing.assert_array_equal(fitted.static_offset[12:], 0.0)
    assert seq.shape.shape == (5, 300)  # the original is untouched


def test_fit_to_model_drops_offsets_of_another_topology():
    model = random_model(n_verts=10, n_shape=10, n_expr=7)
    with pytest.warns(InputWarning, match="12 vertex offsets, more than the model's 10"):
        assert make_sequence().fit_to_model(model).static_offset is None


def test_subset():
    seq = make_sequence(n=10)
    part = seq.subset(1, 8, 3)
    np.testing.assert_array_equal(part.frame_ids, seq.frame_ids[1:8:3])
    for name in ("shape", "expr", "eyes", "K", "w2c", "eyelids"):
        np.testing.assert_array_equal(getattr(part, name), getattr(seq, name)[1:8:3])
    np.testing.assert_array_equal(part.static_offset, seq.static_offset)
    assert len(seq.subset(stop=-2)) == 8
    with pytest.raises(InputError, match=r"frames \[8:2:1\] of a 10-frame sequence are empty"):
        seq.subset(8, 2)
    with pytest.raises(ValueError, match="stride"):
        seq.subset(stride=0)


@pytest.mark.parametrize("camera", [True, False])
def test_canonical_round_trip_is_exact(tmp_path, camera):
    seq = make_sequence(camera=camera, **({} if camera else {"static_offset": None}))
    write_canonical(seq, tmp_path / "seq.npz")
    assert [p.name for p in tmp_path.iterdir()] == ["seq.npz"]  # no temporary left behind
    back = read_canonical(tmp_path / "seq.npz")
    assert back.data_equal(seq) and back.source == str(tmp_path / "seq.npz")
    with np.load(tmp_path / "seq.npz") as z:
        assert int(z["format_version"]) == FORMAT_VERSION and z["expr"].dtype == np.float64
        assert z["frame_ids"].dtype == np.int64 and str(z["source_format"]) == "test"
    assert detect_format(tmp_path / "seq.npz") == "canonical"


def test_canonical_version_and_keys(tmp_path):
    seq = make_sequence()
    write_canonical(seq, tmp_path / "seq.npz")
    arrays = dict(np.load(tmp_path / "seq.npz"))
    np.savez(tmp_path / "newer.npz", **{**arrays, "format_version": np.int64(99)})
    with pytest.raises(InputError, match="key 'format_version': version 99 is newer"):
        read_canonical(tmp_path / "newer.npz")
    np.savez(tmp_path / "extra.npz", **arrays, mystery=np.zeros(2))
    with pytest.warns(InputWarning, match="unknown keys ignored: mystery"):
        read_canonical(tmp_path / "extra.npz")
    del arrays["jaw"]
    np.savez(tmp_path / "nojaw.npz", **arrays)
    with pytest.raises(InputError, match="nojaw.npz: key 'jaw': missing"):
        read_canonical(tmp_path / "nojaw.npz")


def test_unrecognised_inputs_list_the_formats(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(
        InputError, match="notes.txt: unrecognised input; supported formats: canonical"
    ):
        detect_format(tmp_path / "notes.txt")
    np.savez(tmp_path / "other.npz", a=np.zeros(2))
    with pytest.raises(InputError, match=r"keys \['a'\] matches no format; supported formats"):
        read_sequence(tmp_path / "other.npz")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="empty: unrecognised input"):
        read_sequence(tmp_path / "empty")
    with pytest.raises(InputError, match="missing.npz: not found"):
        read_sequence(tmp_path / "missing.npz")
    with pytest.raises(InputError, match="a camera choice applies to vhap input"):
        read_sequence(tmp_path / "other.npz", "driving-clip", camera=1)


def test_convert_command(tmp_path):
    write_vhap_export(tmp_path / "vhap", timesteps=(0, 1, 2))
    out = tmp_path / "out" / "seq.npz"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "archhead_addon",
            "convert",
            str(tmp_path / "vhap"),
            str(out),
            "--fps",
            "50",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == (
        f"{out}: 3 frames, 50 fps, from vhap, shape 300, expr 100, camera 512x520"
    )
    back = read_canonical(out)
    assert back.data_equal(read_sequence(tmp_path / "vhap", fps=50))


def test_convert_errors_and_warnings(tmp_path, capsys):
    assert main(["convert", str(tmp_path / "nothing"), str(tmp_path / "o.npz")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {tmp_path / 'nothing'}: not found"
    write_vhap_export(tmp_path / "vhap", timesteps=(0,))
    assert main(["convert", str(tmp_path / "vhap"), str(tmp_path / "o.npz")]) == 0
    assert "warning: " in capsys.readouterr().err and (tmp_path / "o.npz").is_file()
