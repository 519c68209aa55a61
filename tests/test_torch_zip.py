"""The torch.save reader against real torch.save output, and its refusals."""

import collections
import io
import os
import pickle
import zipfile

import numpy as np
import pytest
import torch

from archhead_addon.io.errors import InputError
from archhead_addon.io.torch_zip import load_torch_file

DTYPES = [
    torch.float64,
    torch.float32,
    torch.float16,
    torch.int64,
    torch.int32,
    torch.int16,
    torch.int8,
    torch.uint8,
    torch.bool,
    torch.complex64,
    torch.complex128,
    torch.uint16,
    torch.uint32,
]


def _save(obj, path, **kwargs):
    torch.save(obj, path, **kwargs)
    return path


def _same(array, tensor):
    expected = tensor.detach().numpy()
    assert isinstance(array, np.ndarray)
    assert array.dtype == expected.dtype and array.shape == expected.shape
    np.testing.assert_array_equal(array, expected)


def test_dtypes(tmp_path):
    gen = torch.Generator().manual_seed(0)
    base = torch.randn(3, 5, generator=gen) * 50
    tensors = {str(d): base.to(d) for d in DTYPES}
    out = load_torch_file(_save(tensors, tmp_path / "dtypes.pt"))
    for key, tensor in tensors.items():
        _same(out[key], tensor)


def test_bfloat16_becomes_float32(tmp_path):
    t = torch.tensor([1.5, -2.25, 3.0e20, -1.0e-20]).to(torch.bfloat16)
    out = load_torch_file(_save({"b": t}, tmp_path / "bf.pt"))["b"]
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, t.float().numpy())


def test_views_strides_offsets_and_shared_storage(tmp_path):
    x = torch.arange(60, dtype=torch.float32).reshape(3, 4, 5)
    views = {
        "transpose": x.transpose(0, 2),
        "slice": x[1:, ::2, 3:],
        "row": x[2, 1],
        "expanded": torch.arange(3.0)[:, None].expand(3, 4),
        "scalar": x[1, 2, 3],
        "empty": x[:, :0],
        "whole": x,
        "flipped_copy": x.flip(0),
    }
    assert views["slice"].storage_offset() > 0 and not views["transpose"].is_contiguous()
    out = load_torch_file(_save(views, tmp_path / "views.pt"))
    for key, tensor in views.items():
        _same(out[key], tensor)
    out["whole"][0, 0, 0] = -1.0  # tensors sharing a storage come back as independent arrays
    assert out["transpose"][0, 0, 0] == 0.0


def test_nested_containers_numpy_parameters_and_metadata(tmp_path):
    obj = {
        "flame": {
            "exp": np.arange(6, dtype=np.float32).reshape(1, 6),
            "shape": torch.ones(1, 4, requires_grad=True),
        },
        "list": [torch.tensor([1, 2]), (np.int64(3), "text", None, 2.5)],
        "param": torch.nn.Parameter(torch.full((2, 2), 7.0)),
        "ordered": torch.nn.Linear(2, 1).state_dict(),
        "frame_id": "00012",
    }
    out = load_torch_file(_save(obj, tmp_path / "nested.frame"))
    np.testing.assert_array_equal(out["flame"]["exp"], obj["flame"]["exp"])
    _same(out["flame"]["shape"], obj["flame"]["shape"])
    _same(out["list"][0], obj["list"][0])
    assert out["list"][1] == (3, "text", None, 2.5)
    _same(out["param"], obj["param"])
    assert list(out["ordered"]) == ["weight", "bias"]
    _same(out["ordered"]["weight"], obj["ordered"]["weight"])
    assert out["frame_id"] == "00012"


def _rewrite(src, dst, change):
    """Copy a zip archive entry by entry, `change(name, data)` returning the new data."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            zout.writestr(info, change(info.filename, zin.read(info.filename)))
    return dst


def test_big_endian_archive(tmp_path):
    t = torch.arange(6, dtype=torch.float64).reshape(2, 3) / 7
    src = _save({"t": t, "u": torch.tensor([1, 300]).to(torch.uint16)}, tmp_path / "le.pt")

    def swap(name, data):
        if name.endswith("byteorder"):
            return b"big"
        if name.endswith("data/0"):
            return np.frombuffer(data, "<f8").astype(">f8").tobytes()
        if name.endswith("data/1"):
            return np.frombuffer(data, "<u2").astype(">u2").tobytes()
        return data

    out = load_torch_file(_rewrite(src, tmp_path / "be.pt", swap))
    _same(out["t"], t)
    np.testing.assert_array_equal(out["u"], [1, 300])


class _Exploit:
    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _zip_with_pickle(path, payload: bytes):
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("archive/data.pkl", payload)
        z.writestr("archive/byteorder", "little")
    return path


def test_malicious_pickle_is_refused_without_running(tmp_path):
    exploit = _Exploit()
    exploit.marker = tmp_path / "pwned"
    path = _zip_with_pickle(tmp_path / "evil.pt", pickle.dumps({"x": exploit}, protocol=2))
    with pytest.raises(InputError, match="allow-list") as err:
        load_torch_file(path)
    assert str(path) in str(err.value)
    assert not exploit.marker.exists()


class _Storage:
    """Pickled as the persistent id of a 4-element float storage (see _TensorPickler)."""


class _Tensor:
    def __init__(self, size, stride):
        self.size, self.stride = size, stride

    def __reduce__(self):
        return (
            torch._utils._rebuild_tensor_v2,
            (_Storage(), 0, self.size, self.stride, False, collections.OrderedDict()),
        )


class _TensorPickler(pickle.Pickler):
    def persistent_id(self, obj):
        return ("storage", torch.FloatStorage, "0", "cpu", 4) if isinstance(obj, _Storage) else None


@pytest.mark.parametrize(
    "size,stride,problem",
    [
        ((4096,), (1,), "reaches element 4095 of a storage of 4 elements"),
        ((2,), (5,), "reaches element 5 of a storage of 4 elements"),
        ((1 << 20, 1 << 20), (0, 0), "needs more bytes than the file holds"),
    ],
)
def test_hostile_tensor_layouts_are_refused(tmp_path, size, stride, problem):
    buf = io.BytesIO()
    _TensorPickler(buf, protocol=2).dump({"t": _Tensor(size, stride)})
    path = _zip_with_pickle(tmp_path / "hostile.pt", buf.getvalue())
    with zipfile.ZipFile(path, "a") as z:
        z.writestr("archive/data/0", np.arange(4, dtype="<f4").tobytes())
    with pytest.raises(InputError, match=problem):
        load_torch_file(path)


def test_legacy_format_is_refused(tmp_path):
    path = _save({"t": torch.ones(2)}, tmp_path / "old.pt", _use_new_zipfile_serialization=False)
    with pytest.raises(InputError, match="legacy torch.save format"):
        load_torch_file(path)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "missing_storage"])
def test_corrupt_files(tmp_path, damage):
    path = _save({"t": torch.arange(100.0)}, tmp_path / "f.pt")
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "garbage":
        path.write_bytes(bytes(range(256)) * 4)
    else:
        buf = io.BytesIO()
        with zipfile.ZipFile(path) as zin, zipfile.ZipFile(buf, "w") as zout:
            for info in zin.infolist():
                if not info.filename.endswith("data/0"):
                    zout.writestr(info, zin.read(info.filename))
        path.write_bytes(buf.getvalue())
    with pytest.raises(InputError) as err:
        load_torch_file(path)
    assert str(path) in str(err.value)
