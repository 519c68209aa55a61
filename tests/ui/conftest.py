"""Fixtures of the UI suite (ui_session.py says what a session does)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ui_session import OUT, REPO, SUITE, BlenderSession, build_zip

from scripts import blender_env


def _label() -> str:
    """The label "Blender 5.2.2 (sid)", from the env's dpkg database ("?" before a build)."""
    return blender_env.blender_label(blender_env.env_root(SUITE), SUITE)


def pytest_report_header(config):
    return f"UI suite binary: {_label()}, env {blender_env.env_root(SUITE)}, out {OUT}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Every failing UI test names the binary it failed in (in the short summary too), so
    the two runs of `make test-ui` cannot be told apart only by their order."""
    outcome = yield
    report = outcome.get_result()
    if not report.failed:
        return
    label = _label()
    report.sections.append(("Blender binary", label))
    crash = getattr(report.longrepr, "reprcrash", None)
    if crash is not None and not crash.message.startswith(label):
        crash.message = f"{label}: {crash.message}"


@pytest.fixture(scope="session")
def blender_session():
    """The mounted env with the extension installed in a clean profile (once a session)."""
    start = time.monotonic()
    root = blender_env.ensure_env(suite=SUITE)
    build_s = time.monotonic() - start
    OUT.mkdir(parents=True, exist_ok=True)
    with blender_env.env_lock(root), blender_env.mounted(root):
        profile = OUT / "profile"
        if profile.exists():
            shutil.rmtree(profile)
        profile.mkdir(parents=True)
        session = BlenderSession(root, profile)
        session.times["env"] = round(build_s, 1)
        zip_path = build_zip(OUT / "dist")
        session.zip = zip_path
        install = OUT / "install"
        text = session.batch(
            ["--command", "extension", "install-file", "-r", "user_default", "-e", str(zip_path)],
            install,
            "install",
            quiet=10,
        )
        session.version = text
        session.ui("setup_profile.py", install, sys.executable, quiet=30)
        yield session
        (OUT / "times.json").write_text(json.dumps(session.times, indent=1))


@pytest.fixture(scope="session")
def ui_data(blender_session) -> dict[str, Path]:
    """Inputs made on the host once a session: a tracked sequence (the built-in
    talking head, 24 frames) and an untrained avatar of the built-in model."""
    import numpy as np  # noqa: F401 - the sequence writer needs it

    from archhead_addon.sequences import write_canonical
    from archhead_addon.sequences.demo import demo_sequence

    folder = OUT / "data"
    folder.mkdir(parents=True, exist_ok=True)
    sequence = folder / "talking_head.npz"
    if not sequence.exists():
        write_canonical(demo_sequence(frames=24), sequence)
    avatar = folder / "untrained_avatar.npz"
    if not avatar.exists():
        subprocess.run(
            [
                "nice",
                "-n",
                "15",
                sys.executable,
                "-m",
                "archhead_addon.avatar.untrained",
                str(avatar),
            ],
            check=True,
            cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO)},
        )
    return {"sequence": sequence, "avatar": avatar, "folder": folder}


@pytest.fixture(scope="session")
def saved_scene(blender_session, ui_data):
    """scene_workflow.py's run (import, load, decode, LOD, driver) and the .blend it saved."""
    out = OUT / "scene_workflow"
    if out.exists():
        shutil.rmtree(out)
    blend = out / "scene.blend"
    result = blender_session.ui(
        "scene_workflow.py", out, str(ui_data["sequence"]), str(ui_data["avatar"]), str(blend)
    )
    return result, blend


@pytest.fixture(scope="session")
def tiny_config() -> Path:
    """The tiny config (tests/training_subject.py) for runs that go to the end (the demo)."""
    from training_subject import TINY_CONFIG

    path = OUT / "data" / "tiny.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**TINY_CONFIG, "stage1_steps": 600, "checkpoint_every": 50}))
    return path


@pytest.fixture(scope="session")
def cancelled_config() -> Path:
    """The tiny config for runs that are cancelled or quit: steps to spare at any speed (at
    0.02 s a step, 600 once finished before the quit arrived)."""
    from training_subject import TINY_CONFIG

    path = OUT / "data" / "tiny_long.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**TINY_CONFIG, "stage1_steps": 20000, "checkpoint_every": 50}))
    return path
