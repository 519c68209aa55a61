"""Session set-up and fixtures shared by every test module.

OpenMP threads that spin while they wait (libgomp's default) made small torch and splat
operations 20-30x slower on a busy 2-core machine; passive waiting keeps them fast. It must
be set before torch or the splat kernel loads OpenMP, hence here (pytest imports conftest
first).

Markers (pyproject.toml): `blender` (real Blender through the bpy module), `slow` (a minute or
more on two cores, its fixtures included), `gpu` (CUDA; skipped without it). Select with `-m`,
e.g. `pytest -m "not slow"`. No test is `slow` today: the longest (the error-against-run-time
report's, the tracker's on rendered clips) spend 15-30 s of CPU time, fixtures included;
with other jobs loading the two cores 3 to 5 times over they took 40-80 s of wall time.

Fixtures: `repo_root`; `extension_zip` (built as `make extension` builds it); `addon` (that
zip installed and enabled in the bpy module, once per session, removed at its end);
`tiny_subject` (a tiny synthetic subject to train on); `tiny_checkpoint` (an untrained avatar
of the built-in model); `demo_scene` (a fresh scene with the moving demo head imported).
"""

import importlib
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# Scripts the tests start (bpy processes) must run this checkout's packages even while the
# session's installed extension has its wheel in the user profile's extensions/.local.
_ROOT = str(Path(__file__).resolve().parents[1])
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (_ROOT, os.environ.get("PYTHONPATH")) if p)

EXTENSION_REPO = "archhead_tests"  # the extension repository the session installs into
DEMO_FRAMES = 6


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def extension_zip(tmp_path_factory) -> Path:
    """The add-on's zip, built by scripts/build_extension.py (`make extension`)."""
    from scripts.build_extension import build

    return build(tmp_path_factory.mktemp("extension"))


@pytest.fixture(scope="session")
def addon(extension_zip):
    """The add-on installed the way Blender does (`extensions.package_install_files`, which
    also installs the zip's wheel of archhead_addon and archhead_blender) and enabled in the
    bpy module; the module Blender imported it as (bl_ext.archhead_tests.archhead).

    At the end of the session the wheel's contents are removed by name: Blender puts an
    extension's wheels into the user profile's shared `extensions/.local` site-packages,
    which every later bpy process puts on sys.path, so a stale copy of the packages left
    there would shadow the checkout. (Tests that load files may have dropped the session's
    repository from the preferences already.)"""
    import bpy

    repo_dir = Path(tempfile.mkdtemp(prefix="archhead_ext_"))
    bpy.context.preferences.extensions.repos.new(
        name=EXTENSION_REPO, module=EXTENSION_REPO, custom_directory=str(repo_dir), source="USER"
    )
    bpy.ops.extensions.package_install_files(
        filepath=str(extension_zip), repo=EXTENSION_REPO, enable_on_install=True
    )
    yield importlib.import_module(f"bl_ext.{EXTENSION_REPO}.archhead")
    local = Path(bpy.utils.user_resource("EXTENSIONS", path=".local"))
    for site in local.glob("lib/python*/site-packages"):
        for name in ("archhead_addon", "archhead_blender", "archhead-*.dist-info"):
            for path in site.glob(name):
                shutil.rmtree(path)
    shutil.rmtree(repo_dir, ignore_errors=True)


@pytest.fixture(scope="session")
def tiny_subject(tmp_path_factory, repo_root) -> Path:
    """A tiny synthetic subject rendered with Cycles through bpy (~5 s): 8 frames of 48x48 px,
    7 train, 1 test (training_subject.FRAMES, SIZE)."""
    from training_subject import FRAMES, SIZE

    folder = tmp_path_factory.mktemp("tiny_subject")
    subprocess.run(
        [
            sys.executable,
            str(repo_root / "scripts" / "synthetic_subject.py"),
            "--out",
            str(folder),
            "--frames",
            str(FRAMES),
            "--size",
            str(SIZE),
            "--samples",
            "8",
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return folder


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory) -> Path:
    """An untrained avatar of the built-in model (the model's own initialisation, seed 0)."""
    import torch

    from archhead_addon.avatar.checkpoint import save_avatar
    from archhead_addon.avatar.model import ArchHeadAvatar
    from archhead_addon.flame import load_model

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("checkpoint") / "tiny_avatar.npz"
    save_avatar(path, ArchHeadAvatar.create(load_model()))
    return path


@pytest.fixture(scope="session")
def demo_scene(addon):
    """make(folder, frames=6): a fresh scene with the demo talking head imported, also
    translating sideways (so the root bone carries a translation besides the expressions'
    joint shift); returns (head object, sequence)."""
    import bpy

    from archhead_addon.sequences.canonical import write_canonical
    from archhead_addon.sequences.demo import demo_sequence

    def make(folder: Path, frames: int = DEMO_FRAMES):
        bpy.ops.wm.read_homefile(use_empty=True)
        seq = demo_sequence(frames=frames, image_size=(64, 64))
        x = np.linspace(-0.03, 0.03, frames)
        seq = replace(seq, translation=np.stack([x, 0.01 * x, np.zeros(frames)], 1))
        path = Path(folder) / "demo.npz"
        write_canonical(seq, path)
        assert bpy.ops.archhead.import_sequence(filepath=str(path)) == {"FINISHED"}
        return bpy.data.objects["demo"], seq

    return make


def pytest_addoption(parser):
    parser.addoption(
        "--ui",
        action="store_true",
        help="run the UI suite (tests/ui, marker `ui`: a Blender binary; make test-ui)",
    )


def pytest_collection_modifyitems(config, items):
    """A `gpu` test without CUDA is skipped, not failed (CI has no GPU). `ui` tests run only
    with --ui (`make test-ui`); `make test` deselects them."""
    if not config.getoption("--ui"):
        ui = [item for item in items if item.get_closest_marker("ui")]
        if ui:
            config.hook.pytest_deselected(items=ui)
            items[:] = [item for item in items if not item.get_closest_marker("ui")]
    try:
        import torch

        cuda = torch.cuda.is_available()
    except ImportError:
        cuda = False
    skip = pytest.mark.skip(reason="needs a CUDA device")
    for item in items:
        if "gpu" in item.keywords and not cuda:
            item.add_marker(skip)
