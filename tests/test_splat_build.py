"""Building and loading the splat kernel: idempotent build, clear messages when the compiler
or the library is missing or stale, and a torch-free numpy path (what Blender runs)."""

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from archhead_addon.splat import build, kernel, scenes

PACKAGE = Path(build.__file__).resolve().parents[1]  # archhead_addon/


def test_build_is_idempotent():
    path = build.build()
    stamp = (path.stat().st_mtime_ns, build.STAMP_PATH.read_text())
    assert build.build() == path
    assert (path.stat().st_mtime_ns, build.STAMP_PATH.read_text()) == stamp
    assert build.is_current()


def test_the_sources_build_and_render_without_x86_intrinsics(tmp_path, monkeypatch):
    """Where immintrin.h is absent (ARM: the plain build, baseline path only), the sources
    still compile and render as the x86 paths do; simulated by renaming __x86_64__ away."""
    for src in build.sources():
        (tmp_path / src.name).write_text(src.read_text().replace("__x86_64__", "AH_NOT_X86"))
    lib_path = tmp_path / "libgeneric.so"
    cmd = [build.find_compiler(), *build.FLAGS, str(tmp_path / "splat.cpp"), "-o", str(lib_path)]
    subprocess.run(cmd, check=True, capture_output=True)
    scene = scenes.face_scene(800, width=40, height=32, seed=1)
    g, settings = scene.gaussians.checked(), scene.settings(background=(0.2, 0.4, 0.6))
    x86 = kernel.forward(g, settings)[0]
    monkeypatch.setattr(kernel, "_lib", None)
    monkeypatch.setattr(build, "ensure_library", lambda: lib_path)
    assert kernel.supported_simd() == ["baseline"]
    plain = kernel.forward(g, settings)[0]
    for a, b in zip(plain, x86, strict=True):  # round-off: the x86 paths may fuse products
        diff = np.abs(a - b)
        assert diff.max() <= 1 / 255 + 1e-6 and diff.mean() <= 1e-6


def test_missing_compiler_says_what_to_install(tmp_path):
    with pytest.raises(build.BuildError, match="No C\\+\\+ compiler found") as err:
        build.find_compiler({"PATH": str(tmp_path)})
    assert "apt install g++" in str(err.value) and "first use" in str(err.value)
    with pytest.raises(build.BuildError, match="no-such-compiler"):
        build.find_compiler({"PATH": "/usr/bin:/bin", "CXX": "no-such-compiler"})


def run_copy(tmp_path, code, path=None):
    """Run code against a copy of the package (its build directory as prepared), with the
    kernel cache in tmp_path/cache and PATH `path` (default: this process's)."""
    env = {"PYTHONPATH": str(tmp_path), "ARCHHEAD_CACHE": str(tmp_path / "cache")}
    env["PATH"] = os.environ["PATH"] if path is None else path
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
    )


def copy_package(tmp_path, with_build):
    """The splat package and the modules it imports, as a fresh checkout would have them."""
    dst = tmp_path / "archhead_addon"
    ignore = shutil.ignore_patterns("__pycache__", *(() if with_build else ("_build",)))
    shutil.copytree(PACKAGE / "splat", dst / "splat", ignore=ignore)
    for name in ("__init__.py", "camera.py", "paths.py", "rotations.py"):
        shutil.copy(PACKAGE / name, dst / name)
    return dst


LOAD = "from archhead_addon.splat import kernel; print(kernel.library()._name)"


def test_an_installed_copy_compiles_the_kernel_once_into_the_cache(tmp_path):
    """An extension ships sources only: the first use compiles into the user's cache, which
    a reinstall leaves alone, and later processes load that library as it is."""
    copy_package(tmp_path, with_build=False)
    first = run_copy(tmp_path, LOAD)
    assert first.returncode == 0, first.stderr
    assert "compiling the splat kernel (first use)" in first.stderr
    built = Path(first.stdout.strip())
    assert built.is_relative_to(tmp_path / "cache" / "kernel")
    stamp = built.stat().st_mtime_ns
    again = run_copy(tmp_path, LOAD)
    assert again.returncode == 0 and "compiling" not in again.stderr
    assert Path(again.stdout.strip()) == built and built.stat().st_mtime_ns == stamp


def test_without_a_compiler_the_loader_says_what_to_install(tmp_path):
    copy_package(tmp_path, with_build=False)
    result = run_copy(tmp_path, LOAD, path=str(tmp_path))
    assert result.returncode != 0
    assert "KernelNotBuiltError" in result.stderr and "apt install g++" in result.stderr
    check = "from archhead_addon.splat import build; print(build.unavailable_reason())"
    assert "No C++ compiler found" in run_copy(tmp_path, check, path=str(tmp_path)).stdout
    assert run_copy(tmp_path, check).stdout.strip() == "None"  # compiles on first use


def test_a_stale_package_library_is_not_loaded(tmp_path):
    build.build()
    dst = copy_package(tmp_path, with_build=True)
    fresh = run_copy(tmp_path, LOAD)
    assert Path(fresh.stdout.strip()) == dst / "splat" / "_build" / build.LIB_NAME
    with open(dst / "splat" / "csrc" / "splat.cpp", "a") as f:
        f.write("// edited\n")
    stale = run_copy(tmp_path, LOAD)
    assert stale.returncode == 0, stale.stderr
    assert Path(stale.stdout.strip()).is_relative_to(tmp_path / "cache" / "kernel")


def test_numpy_path_does_not_import_torch(tmp_path):
    build.build()
    copy_package(tmp_path, with_build=True)
    result = run_copy(
        tmp_path,
        """
        import sys
        import numpy as np
        from archhead_addon.splat import blender_render, kernel, scenes
        s = scenes.face_scene(200, 32, 32)
        r = kernel.render_frame(s.gaussians, s.settings())
        assert r.alpha.max() > 0.9
        assert "torch" not in sys.modules, "torch was imported"
        print("ok")
        """,
    )
    assert result.stdout.strip() == "ok", result.stderr
