"""A real Blender binary for the UI tests (`make test-ui`): Debian's `blender` package in a
`debootstrap` chroot, built once and reused from the cache.

    python scripts/blender_env.py build            # build, or reuse when cached; prints the root
    python scripts/blender_env.py run -- CMD ...   # CMD inside the env (mounts set up and removed)
    python scripts/blender_env.py version          # the Blender version the env has
    python scripts/blender_env.py remove           # delete the cached env

Two suites, chosen with `--suite` or `$ARCHHEAD_BLENDER_SUITE` (default trixie): trixie has
Blender 4.3.2, the manifest's 4.2 LTS end; sid has the newest Debian Blender (5.2.2, Python
3.14). `make test-ui` runs the UI suite in both, trixie first.

    ARCHHEAD_BLENDER_SUITE=sid python scripts/blender_env.py build
    python scripts/blender_env.py --suite sid run -- blender --version

The trixie env lives in `$ARCHHEAD_BLENDER_ENV` when set; every env else in
`$ARCHHEAD_CACHE/blender-env/<suite>`, else `~/.cache/archhead/blender-env/<suite>`.
Building needs root and Debian's archive: `debootstrap --variant=minbase <suite>`
(debootstrap is installed on the host with apt-get when missing), then, inside, `apt-get
install blender python3-numpy xvfb xauth libegl1 libegl-mesa0` (Debian's blender lacks numpy;
EEVEE in `blender -b` needs EGL). sid's Release file may be past its Valid-Until date, so apt
runs there with `Acquire::Check-Valid-Until=false` (also written into the env's apt.conf.d).
A stamp file holding the suite's recipe marks a finished env; a different recipe or a
half-built folder is built anew.

What a chroot needs for Blender and apt: /proc (Blender finds its data through
/proc/self/exe; apt's maintainer scripts), /dev bound from the host (/dev/null, urandom),
a private tmpfs on /dev/shm (Mesa's software OpenGL and Python's multiprocessing) and one on
/tmp (the X server's sockets and lock files; private, so the host's /tmp is never touched).
Host folders the tests need (the checkout, the backend Python's environment and its base
interpreter) are bound at the same paths, read-only except the checkout. `mounted()` sets all
this up and takes it down in reverse order however the body ends; it also removes mounts left
by a killed earlier run, and `kill_processes()` ends every process whose root is the env (a
Blender, its Xvfb, a training backend) by its id.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

MIRROR = "http://deb.debian.org/debian"
# libegl1 + libegl-mesa0: `blender -b` renders EEVEE through a headless EGL context
PACKAGES = ("blender", "python3-numpy", "xvfb", "xauth", "libegl1", "libegl-mesa0")
# The suites an env can be built from, oldest Blender first: trixie has Blender 4.3.2 (the
# manifest's 4.2 LTS end), sid the newest Debian packages (Blender 5.2.2 with Python 3.14).
SUITES = ("trixie", "sid")
DEFAULT_SUITE = "trixie"
SUITE_VARIABLE = "ARCHHEAD_BLENDER_SUITE"
# sid's Release file can be past its Valid-Until date (this machine's clock is ahead of the
# archive's last signing); apt is told not to check that date there. debootstrap does not
# check it (it verifies the Release signature and the packages' hashes only).
NO_VALID_UNTIL = {"sid"}
# Blender 5.2's extensions add-on (bl_pkg) imports cattrs and requests when it registers,
# which Debian's blender 5.2.2 does not depend on: without them every start prints a
# traceback ("No module named 'cattrs'") and the Extensions system is not registered.
SID_PACKAGES = ("python3-cattr", "python3-requests")
# What each suite's finished env holds; trixie's is unchanged so its cached env stays valid.
RECIPES = {
    "trixie": {"suite": "trixie", "variant": "minbase", "packages": list(PACKAGES), "version": 2},
    "sid": {
        "suite": "sid",
        "variant": "minbase",
        "packages": [*PACKAGES, *SID_PACKAGES],
        "version": 2,
    },
}
STAMP = "archhead-blender-env.json"
# Kept for callers of the single-suite module.
SUITE = DEFAULT_SUITE
RECIPE = RECIPES[DEFAULT_SUITE]


def suite_name(suite: str | None = None) -> str:
    """The suite asked for: `suite`, else $ARCHHEAD_BLENDER_SUITE, else trixie."""
    name = suite or os.environ.get(SUITE_VARIABLE) or DEFAULT_SUITE
    if name not in RECIPES:
        raise SystemExit(f"unknown Blender env suite {name!r}: one of {', '.join(SUITES)}")
    return name


def env_root(suite: str | None = None) -> Path:
    """The suite's env folder: for the default suite (trixie) $ARCHHEAD_BLENDER_ENV when set,
    else (any suite) its folder in the cache."""
    suite = suite_name(suite)
    if suite == DEFAULT_SUITE and os.environ.get("ARCHHEAD_BLENDER_ENV"):
        return Path(os.environ["ARCHHEAD_BLENDER_ENV"]).resolve()
    cache = Path(os.environ.get("ARCHHEAD_CACHE") or Path.home() / ".cache" / "archhead")
    return (cache / "blender-env" / suite).resolve()


def log(message: str) -> None:
    print(f"[blender-env] {message}", file=sys.stderr, flush=True)


def is_ready(root: Path, suite: str | None = None) -> bool:
    try:
        return json.loads((root / STAMP).read_text()) == RECIPES[suite_name(suite)]
    except (OSError, ValueError):
        return False


@contextlib.contextmanager
def env_lock(root: Path) -> Iterator[None]:
    """One builder or user of an env at a time (two test runs would share its mounts)."""
    root.parent.mkdir(parents=True, exist_ok=True)
    with open(root.parent / f".{root.name}.lock", "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _run(cmd: list[str], **kwargs) -> None:
    log("$ " + " ".join(cmd))
    subprocess.run(cmd, check=True, **kwargs)


def ensure_env(root: Path | None = None, suite: str | None = None) -> Path:
    """The suite's env root, built first when missing or built from another recipe."""
    root = root or env_root(suite)
    suite = suite_name(suite)
    if is_ready(root, suite):
        return root
    with env_lock(root):
        if is_ready(root, suite):
            return root
        _build(root, suite)
    return root


def _build(root: Path, suite: str) -> None:
    if os.geteuid() != 0:
        raise SystemExit("building the Blender env needs root (debootstrap, chroot, mount)")
    start = time.monotonic()
    partial = root.with_name(root.name + ".partial")
    for path in (partial, root):
        _remove(path)
    if not shutil.which("debootstrap"):
        env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
        _run(["apt-get", "update"], env=env)
        _run(["apt-get", "install", "-y", "debootstrap"], env=env)
    partial.mkdir(parents=True)
    apt_options: list[str] = []
    if suite in NO_VALID_UNTIL:
        apt_options = ["-o", "Acquire::Check-Valid-Until=false"]
    _run(["debootstrap", "--variant=minbase", suite, str(partial), MIRROR])
    if apt_options:
        # Every later apt run in the env (the install below, a user's) skips the date check.
        conf = partial / "etc/apt/apt.conf.d/99archhead-no-valid-until"
        conf.write_text('Acquire::Check-Valid-Until "false";\n')
    # No services start inside a chroot.
    policy = partial / "usr/sbin/policy-rc.d"
    policy.write_text("#!/bin/sh\nexit 101\n")
    policy.chmod(0o755)
    with mounted(partial, binds=()):
        apt_env = {"DEBIAN_FRONTEND": "noninteractive"}
        chroot_run(partial, ["apt-get", *apt_options, "update"], env=apt_env, check=True)
        chroot_run(
            partial,
            [
                "apt-get",
                *apt_options,
                "install",
                "-y",
                "--no-install-recommends",
                *RECIPES[suite]["packages"],
            ],
            env=apt_env,
            check=True,
        )
        chroot_run(partial, ["apt-get", "clean"], env=apt_env, check=True)
    (partial / STAMP).write_text(json.dumps(RECIPES[suite]))
    partial.rename(root)
    log(f"built {root} in {time.monotonic() - start:.0f} s")


def _mountpoints_under(root: Path) -> list[str]:
    """Mount points at or below root, deepest first (from /proc/self/mountinfo)."""
    prefix = str(root)
    points = []
    with open("/proc/self/mountinfo") as handle:
        for line in handle:
            point = line.split()[4].replace("\\040", " ")
            if point == prefix or point.startswith(prefix + "/"):
                points.append(point)
    return sorted(set(points), key=lambda p: (-p.count("/"), p))


def unmount_all(root: Path) -> None:
    """Unmount everything below root (a killed earlier run's mounts included)."""
    kill_processes(root)
    for point in _mountpoints_under(root):
        if subprocess.run(["umount", point], capture_output=True).returncode != 0:
            subprocess.run(["umount", "-l", point], capture_output=True)


def _remove(path: Path) -> None:
    """Delete an env folder, never while anything is mounted below it (a bound checkout
    would be deleted with it)."""
    if not path.exists():
        return
    unmount_all(path)
    left = _mountpoints_under(path)
    if left:
        raise SystemExit(f"not removing {path}: still mounted: {left}")
    shutil.rmtree(path)


def processes_in(root: Path) -> list[int]:
    """Ids of the processes whose root directory is the env."""
    found = []
    target = str(root)
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if os.readlink(entry / "root") == target:
                found.append(int(entry.name))
        except OSError:
            continue
    return found


def kill_processes(root: Path, grace: float = 5.0) -> list[int]:
    """End every process inside the env: SIGTERM, then SIGKILL after `grace` seconds.
    Returns the ids that were still running."""
    pids = processes_in(root)
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and processes_in(root):
        time.sleep(0.1)
    for pid in processes_in(root):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and processes_in(root):
        time.sleep(0.1)
    return pids


def default_binds() -> list[Path]:
    """Host folders bound into the env at the same paths: the checkout (read-write) and the
    running Python's environment and base interpreter (the add-on's Backend Python)."""
    repo = Path(__file__).resolve().parents[1]
    binds = [repo]
    for prefix in (sys.prefix, sys.base_prefix):
        path = Path(prefix).resolve()
        if not any(path == b or b in path.parents for b in binds):
            binds.append(path)
    return binds


@contextlib.contextmanager
def mounted(root: Path, binds: list[Path] | tuple = None) -> Iterator[Path]:
    """/proc, /dev, /dev/shm, /tmp and the bound host folders inside root, all taken down
    again (processes inside ended first) however the body ends."""
    binds = default_binds() if binds is None else list(binds)
    unmount_all(root)
    done: list[str] = []

    def mount(args: list[str], point: Path) -> None:
        point.mkdir(parents=True, exist_ok=True)
        subprocess.run(["mount", *args, str(point)], check=True)
        done.append(str(point))

    try:
        mount(["-t", "proc", "proc"], root / "proc")
        mount(["--bind", "/dev"], root / "dev")
        mount(["-t", "tmpfs", "-o", "mode=1777", "shm"], root / "dev/shm")
        mount(["-t", "tmpfs", "-o", "mode=1777", "tmp"], root / "tmp")
        for index, host in enumerate(binds):
            host = Path(host)
            point = root / host.relative_to("/")
            mount(["--bind", str(host)], point)
            if index > 0:  # the checkout stays writable; environments are read-only
                subprocess.run(["mount", "-o", "remount,bind,ro", str(point)], check=True)
        resolv = Path("/etc/resolv.conf")
        if resolv.exists():
            shutil.copyfile(resolv, root / "etc/resolv.conf")
        yield root
    finally:
        kill_processes(root)
        for point in reversed(done):
            if subprocess.run(["umount", point], capture_output=True).returncode != 0:
                subprocess.run(["umount", "-l", point], capture_output=True)
        left = _mountpoints_under(root)
        if left:
            log(f"still mounted after clean-up: {left}")


BASE_ENV = {
    "PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
    "LANG": "C.UTF-8",
    "HOME": "/root",
}


def chroot_run(
    root: Path,
    argv: list[str],
    env: dict[str, str] | None = None,
    cwd: str = "/",
    check: bool = False,
    timeout: float | None = None,
    **kwargs,
) -> subprocess.CompletedProcess:
    """Run argv inside a mounted env, niced, with a clean environment plus `env`. On a
    timeout every process in the env is ended and TimeoutExpired is raised."""
    full_env = {**BASE_ENV, **(env or {})}
    cmd = ["nice", "-n", "15", "chroot", str(root), "/usr/bin/env", "-C", cwd, *argv]
    proc = subprocess.Popen(cmd, env=full_env, **kwargs)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        kill_processes(root)
        proc.kill()
        proc.wait()
        raise
    result = subprocess.CompletedProcess(cmd, proc.returncode, out, err)
    if check and proc.returncode != 0:
        raise subprocess.CalledProcessError(proc.returncode, argv, out, err)
    return result


def package_version(root: Path, package: str = "blender") -> str:
    """A Debian package's version in the env, from its dpkg database (no chroot needed):
    "5.2.2+dfsg-1"; "" when it is not installed."""
    try:
        text = (root / "var/lib/dpkg/status").read_text(errors="replace")
    except OSError:
        return ""
    for stanza in text.split("\n\n"):
        fields = dict(
            line.split(": ", 1) for line in stanza.splitlines() if ": " in line and line[0] != " "
        )
        if fields.get("Package") == package and "installed" in fields.get("Status", ""):
            return fields.get("Version", "")
    return ""


def blender_label(root: Path, suite: str | None = None) -> str:
    """The label "Blender 5.2.2 (sid)": which binary a test ran in, for failure messages."""
    version = package_version(root).split("+")[0].split("-")[0] or "?"
    return f"Blender {version} ({suite_name(suite)})"


def blender_version(root: Path) -> str:
    with mounted(root, binds=()):
        result = chroot_run(
            root, ["blender", "--version"], stdout=subprocess.PIPE, text=True, check=True
        )
    return result.stdout.splitlines()[0].strip()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=["build", "run", "version", "remove", "path"])
    parser.add_argument(
        "--suite",
        choices=SUITES,
        default=None,
        help=f"Debian suite of the env (default: ${SUITE_VARIABLE}, else {DEFAULT_SUITE})",
    )
    parser.add_argument("cmd", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    suite = suite_name(args.suite)
    root = env_root(args.suite)
    if args.action == "path":
        print(root)
    elif args.action == "build":
        print(ensure_env(root, suite))
    elif args.action == "version":
        print(blender_version(ensure_env(root, suite)))
    elif args.action == "remove":
        with env_lock(root):
            for path in (root, root.with_name(root.name + ".partial")):
                _remove(path)
    else:
        cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
        root = ensure_env(root, suite)
        with env_lock(root), mounted(root):
            return chroot_run(root, cmd or ["bash"], cwd=os.getcwd()).returncode
    return 0


if __name__ == "__main__":
    sys.exit(main())
