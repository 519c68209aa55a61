"""Session set-up and fixtures shared by every test module.

OpenMP threads that spin while they wait (libgomp's default) made small torch and splat
operations 20-30x slower on a busy 2-core machine; passive waiting keeps them fast. It must
be set before torch or the splat kernel loads OpenMP, hence here (pytest imports conftest
first).

Markers (pyproject.toml): `blender` (real Blender through the bpy module), `slow` (training
or Cycles renders: a minute or more on two cores), `gpu` (CUDA; skipped without it). Select
with `-m`, e.g. `pytest -m "not slow"`.
"""

import os
from pathlib import Path

import pytest

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# Scripts the tests start (bpy processes) must run this checkout's packages even while the
# session's installed extension has its wheel in the user profile's extensions/.local.
_ROOT = str(Path(__file__).resolve().parents[1])
os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (_ROOT, os.environ.get("PYTHONPATH")) if p)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def addon():
    """The add-on, built as `make extension` builds it, installed and enabled in the bpy
    module (once per session); the module Blender imported it as."""
    from addon_env import installed_addon

    return installed_addon()


@pytest.fixture(scope="session")
def extension_zip(addon) -> Path:
    """The zip the `addon` fixture installed."""
    from addon_env import state

    return state()["zip"]


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


def pytest_sessionfinish(session, exitstatus):
    """Uninstall the session's extension, however a test installed it (addon_env)."""
    from addon_env import uninstall_addon

    uninstall_addon()
