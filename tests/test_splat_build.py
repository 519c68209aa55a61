"""Building and loading the splat kernel: idempotent build, clear messages when the compiler
or the library is missing or stale, and a torch-free numpy path (what Blender runs)."""

import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from archhead_addon.splat import build

PACKAGE = Path(build.__file__).resolve().parents[1]  # archhead_addon/


def test_build_is_idempotent():
    path = build.build()
    stamp = (path.stat().st_mtime_ns, build.STAMP_PATH.read_text())
    assert build.build() == path
    assert (path.stat().st_mtime_ns, build.STAMP_PATH.read_text()) == stamp
    assert build.is_current()


def test_missing_compiler_says_what_to_install(tmp_path):
    with pytest.raises(build.BuildError, match="No C\\+\\+ compiler found") as err:
        build.find_compiler({"PATH": str(tmp_path)})
    assert "apt install g++" in str(err.value) and "make setup" in str(err.value)
    with pytest.raises(build.BuildError, match="no-such-compiler"):
        build.find_compiler({"PATH": "/usr/bin:/bin", "CXX": "no-such-compiler"})


def run_copy(tmp_path, code):
    """Run code against a copy of the package (its build directory as prepared)."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={"PYTHONPATH": str(tmp_path)},
    )


def copy_package(tmp_path, with_build):
    """The splat package and the modules it imports, as a fresh checkout would have them."""
    dst = tmp_path / "archhead_addon"
    ignore = shutil.ignore_patterns("__pycache__", *(() if with_build else ("_build",)))
    shutil.copytree(PACKAGE / "splat", dst / "splat", ignore=ignore)
    for name in ("__init__.py", "camera.py", "rotations.py"):
        shutil.copy(PACKAGE / name, dst / name)
    return dst


LOAD = "from archhead_addon.splat import kernel; kernel.library()"


def test_loader_reports_missing_library(tmp_path):
    copy_package(tmp_path, with_build=False)
    result = run_copy(tmp_path, LOAD)
    assert result.returncode != 0
    assert "KernelNotBuiltError" in result.stderr and "run `make setup`" in result.stderr


def test_loader_reports_stale_library(tmp_path):
    build.build()
    dst = copy_package(tmp_path, with_build=True)
    assert run_copy(tmp_path, LOAD).returncode == 0
    with open(dst / "splat" / "csrc" / "splat.cpp", "a") as f:
        f.write("// edited\n")
    result = run_copy(tmp_path, LOAD)
    assert "older than its sources" in result.stderr and "make setup" in result.stderr


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
        r = kernel.render(*s.gaussians(), kernel.RasterSettings(s.viewmat, s.K, 32, 32))
        assert r.alpha.max() > 0.9
        assert "torch" not in sys.modules, "torch was imported"
        print("ok")
        """,
    )
    assert result.stdout.strip() == "ok", result.stderr
