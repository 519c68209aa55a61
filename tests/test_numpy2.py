"""The Blender-side decode under numpy 2 with every warning an error: Blender brings its own
numpy (Debian's 5.2 the system's, numpy 2), which the project's venv (numpy 1.26) never
meets. `make setup` makes `.venv-numpy2` (numpy alone: 2.5 on the Python 3.12 or later it
finds, as Blender 5.x's 3.13; 2.4 on Python 3.11 where it finds none); the decode there must
give the main venv's Gaussians."""

import subprocess
import sys

import numpy as np
import pytest

DECODE = r"""
import sys, warnings
import numpy as np
warnings.simplefilter("error")
from archhead_addon.avatar.point_attributes import point_attributes
from archhead_addon.avatar.runtime import AvatarRuntime
from archhead_addon.splat.frame import SplatFrame
runtime = AvatarRuntime.load(sys.argv[1])
out = {"numpy": np.array(np.__version__)}
for lod in (0.0, 0.5, 1.0):
    g = runtime.decode(lod, expr=np.full(100, 0.5), jaw=np.array([0.2, 0, 0]),
                       rotation=np.array([0, 0.3, 0]), eyes=np.zeros(6))
    out[f"means_{lod}"], out[f"scales_{lod}"] = g.means, g.log_scales
    points = point_attributes(SplatFrame.from_gaussians(g), np.array([0.0, 0.0, 1.0]))
    out.update({f"{k}_{lod}": v for k, v in points.items()})
np.savez(sys.argv[2], **out)
"""


def _venv_numpy2(repo_root):
    python = repo_root / ".venv-numpy2" / "bin" / "python"
    if not python.is_file():
        pytest.fail(f"{python} is missing: `make setup` makes it (numpy 2 for Blender's side)")
    return python


def test_the_blender_side_decode_runs_on_numpy_2_without_warnings(tmp_path, repo_root):
    python = _venv_numpy2(repo_root)
    avatar = tmp_path / "avatar.npz"
    subprocess.run(
        [sys.executable, "-m", "archhead_addon.avatar.untrained", str(avatar)],
        check=True,
        cwd=repo_root,
        timeout=300,
    )
    results = {}
    for name, exe in (("main", sys.executable), ("numpy2", str(python))):
        out = tmp_path / f"{name}.npz"
        done = subprocess.run(
            [exe, "-W", "error", "-c", DECODE, str(avatar), str(out)],
            cwd=repo_root,
            env={"PYTHONPATH": str(repo_root), "PATH": "/usr/bin:/bin"},
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, f"{name}: {done.stderr[-3000:]}"
        results[name] = dict(np.load(out))
    assert str(results["numpy2"]["numpy"]).startswith("2.")
    assert str(results["main"]["numpy"]).startswith("1.")
    for key in results["main"]:
        if key != "numpy":
            np.testing.assert_allclose(results["numpy2"][key], results["main"][key], atol=1e-5)
