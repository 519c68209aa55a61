"""The UI suite (`make test-ui`, marker `ui`): the extension zip installed into a real Blender
binary's clean user profile, driven under Xvfb.

Once per session: the Blender env (scripts/blender_env.py: built or reused from the cache)
is mounted, `make extension`'s zip is built and installed with Blender's own command line
(`blender --command extension install-file -r user_default -e ZIP`) into a new profile under
out/ui/profile, and Backend Python is set to this Python (its environment has torch; the
env binds it at the same path). Each test runs Blender-side scripts of tests/ui/blender/
(`BlenderSession.ui` for a window under Xvfb, `.batch` for `blender -b`); a failure names the
step and keeps its screenshot in out/ui/<test>/. After every Blender run, no process may be
left in the env (a leftover Blender, Xvfb or backend fails the test and is ended), and a run
that passed may have printed no Python traceback.

The binary is the env of `$ARCHHEAD_BLENDER_SUITE` (trixie, Blender 4.3.2, by default; sid,
Blender 5.2.2): `make test-ui` runs the suite once in each. Another suite than trixie writes
to out/ui-<suite>/ instead of out/ui/, and every failure names the binary ("Blender 5.2.2
(sid): ...").
"""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
import time
from pathlib import Path

from scripts import blender_env

UI_DIR = Path(__file__).resolve().parent
REPO = UI_DIR.parents[1]
SUITE = blender_env.suite_name()
OUT = REPO / "out" / ("ui" if SUITE == blender_env.DEFAULT_SUITE else f"ui-{SUITE}")
SCRIPTS = UI_DIR / "blender"
SCREEN = "1400x900x24"
TRACEBACK = "Traceback (most recent call last):"
# A Blender run, like every wait inside one (blender/ui_driver.py), is given SAFETY times
# the seconds it takes on a quiet machine: the suite passes with other jobs on every core.
SAFETY = float(os.environ.get("ARCHHEAD_UI_SAFETY", "10"))


XVFB_FAILED = "Xvfb failed to start"
XVFB_TRIES = 3


def _free_display() -> int:
    """An X display number nobody uses (the env's /tmp is private, but X's abstract
    sockets are shared with the host). Tried from a random start: two suites starting a
    window at once (trixie and sid side by side) once took the same number."""
    used = Path("/proc/net/unix").read_text()
    numbers = list(range(140, 400))
    first = random.randrange(len(numbers))
    for number in numbers[first:] + numbers[:first]:
        if f"/tmp/.X11-unix/X{number}" not in used and not Path(f"/tmp/.X{number}-lock").exists():
            return number
    raise RuntimeError("no free X display number")


class BlenderRunError(AssertionError):
    pass


class BlenderSession:
    def __init__(self, root: Path, profile: Path):
        self.root, self.profile = root, profile
        self.label = blender_env.blender_label(root, SUITE)  # "Blender 5.2.2 (sid)"
        self.version = ""
        self.times: dict[str, float] = {}

    def env(self, out: Path) -> dict[str, str]:
        return {
            "HOME": str(self.profile),
            "BLENDER_USER_RESOURCES": str(self.profile / "blender"),
            "ARCHHEAD_CACHE": str(self.profile / "archhead-cache"),
            "ARCHHEAD_UI_OUT": str(out),
            "OMP_WAIT_POLICY": "PASSIVE",
            "OMP_NUM_THREADS": "2",
            "PYTHONUNBUFFERED": "1",
            "ARCHHEAD_UI_SAFETY": str(SAFETY),
            **{k: os.environ[k] for k in ("ARCHHEAD_UI_STEP_TIMEOUT",) if k in os.environ},
        }

    def run(self, argv: list[str], out: Path, quiet: float, display: bool, name: str):
        """argv (a blender command line) in the env; its output goes to out/NAME.log.
        Returns (exit code, log text). Fails when a process is left behind, or when it runs
        past SAFETY times `quiet` (about how long it takes on a quiet machine)."""
        timeout = quiet * SAFETY
        out.mkdir(parents=True, exist_ok=True)
        for _ in range(XVFB_TRIES if display else 1):
            code, text = self._run_once(argv, out, timeout, display, name)
            if not (display and code and XVFB_FAILED in text):
                break  # else another display number (one taken meanwhile)
        return code, text

    def _run_once(self, argv, out: Path, timeout: float, display: bool, name: str):
        if display:
            argv = [
                "xvfb-run",
                "-n",
                str(_free_display()),
                "-s",
                f"-screen 0 {SCREEN} -nolisten tcp -fbdir /tmp",
                *argv,
            ]
        log_path = out / f"{name}.log"
        start = time.monotonic()
        with open(log_path, "w") as log:
            try:
                proc = blender_env.chroot_run(
                    self.root,
                    argv,
                    env=self.env(out),
                    cwd=str(REPO),
                    timeout=timeout,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )
                code = proc.returncode
            except subprocess.TimeoutExpired:
                code = None
        self.times[name] = round(time.monotonic() - start, 1)
        text = log_path.read_text(errors="replace")
        time.sleep(0.5)
        left = self.leftovers()
        if code is None:
            raise BlenderRunError(
                f"{self.label}: {name}: no exit after {timeout} s; log {log_path}\n{text[-3000:]}"
            )
        if left:
            raise BlenderRunError(f"{self.label}: {name}: processes left behind: {left}")
        return code, text

    def leftovers(self) -> list[str]:
        """Commands still running in the env (ended here, and reported)."""
        names = []
        for pid in blender_env.processes_in(self.root):
            try:
                names.append(Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ")[:120])
            except OSError:
                continue
        if names:
            blender_env.kill_processes(self.root)
        return names

    def ui(self, script: str, out: Path, *args: str, blend: str | None = None, quiet=180):
        """A Blender window running tests/ui/blender/SCRIPT; returns its result.json.
        A failing step raises with its name, error and screenshot. `quiet`: about how long
        the run takes on a quiet machine (the longest, scene_workflow.py, about 140 s)."""
        argv = ["blender", "--enable-event-simulate", "--python-exit-code", "1"]
        if blend:
            argv.append(str(blend))
        argv += ["--python", str(SCRIPTS / script), "--", *args]
        result_path = out / "result.json"
        if result_path.exists():
            result_path.unlink()
        code, text = self.run(argv, out, quiet, display=True, name=Path(script).stem)
        if not result_path.exists():
            raise BlenderRunError(
                f"{self.label}: {script}: exit {code}, no result.json\n{text[-4000:]}"
            )
        result = json.loads(result_path.read_text())
        if result["status"] != "passed":
            failed = result["steps"][-1] if result["steps"] else {}
            shot = failed.get("screenshot")
            raise BlenderRunError(
                f"{self.label}: {script}: step '{result.get('failed_step')}' failed: "
                f"{failed.get('error')}\n"
                f"screenshot: {out / shot if shot else 'none'}\n"
                f"{failed.get('traceback', '')}\n--- log tail ---\n{text[-3000:]}"
            )
        if code != 0:
            raise BlenderRunError(
                f"{self.label}: {script}: exit {code} after passing steps\n{text[-3000:]}"
            )
        self.no_tracebacks(script, text)
        return result

    def batch(self, args: list[str], out: Path, name: str, quiet=60) -> str:
        """`blender -b ... --python-exit-code 1 ARGS`; returns its output, fails on exit != 0."""
        argv = ["blender", "-b", "--python-exit-code", "1", *args]
        code, text = self.run(argv, out, quiet, display=False, name=name)
        if code != 0:
            raise BlenderRunError(f"{self.label}: {name}: exit {code}\n{text[-4000:]}")
        self.no_tracebacks(name, text)
        return text

    def no_tracebacks(self, name: str, text: str) -> None:
        """A run that passed printed no Python traceback (a handler's, an add-on's that
        failed to register, the binary's own): Blender goes on after them, the artist sees
        them in the console."""
        found = text.find(TRACEBACK)
        if found >= 0:
            raise BlenderRunError(
                f"{self.label}: {name}: a Python traceback in Blender's console\n"
                f"{text[found : found + 3000]}"
            )


def build_zip(out: Path) -> Path:
    """What `make extension` builds (scripts/build_extension.py), into out/."""
    from scripts.build_extension import build

    kernel = REPO / "archhead_addon/splat/_build/libarchhead_splat.so"
    if not kernel.exists():  # a worktree without `make setup`: build the kernel
        subprocess.run([sys.executable, "-m", "archhead_addon.splat.build"], cwd=REPO, check=True)
    if out.exists():
        shutil.rmtree(out)
    return build(out)
