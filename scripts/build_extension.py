"""Build the installable extension zip for this platform (`make extension`):

    .venv/bin/python scripts/build_extension.py [--out dist]

The zip holds the add-on alone: blender_manifest.toml (with `platforms` and `wheels`),
__init__.py, operators/ and panels/, and one wheel with the two packages it imports,
`archhead_addon` (the core, with this platform's compiled splat kernel) and
`archhead_blender` (the Blender side). Blender installs the wheel into its extensions'
site-packages, so inside Blender, as everywhere else, the core is `archhead_addon`.
Scripts, benchmarks, tests and docs stay out. Blender's own `blender_ext.py build` makes the
zip from a staging folder, so what it checks (the manifest, the file set) is checked here.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import platform
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
ADDON_FILES = ("__init__.py", "blender_manifest.toml", "operators", "panels")
PACKAGES = ("archhead_addon", "archhead_blender")
# Blender platform -> the wheel's platform tag (the kernel is a plain shared library loaded
# with ctypes, so the wheel is py3-none-<platform>).
WHEEL_TAGS = {
    "linux-x64": "manylinux_2_28_x86_64",
    "linux-arm64": "manylinux_2_28_aarch64",
    "macos-arm64": "macosx_11_0_arm64",
    "macos-x64": "macosx_10_15_x86_64",
    "windows-x64": "win_amd64",
}
SKIP = ("__pycache__", ".pyc")


def this_platform() -> str:
    machine = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}
    system = {"Linux": "linux", "Darwin": "macos", "Windows": "windows"}[platform.system()]
    return f"{system}-{machine[platform.machine().lower()]}"


def manifest() -> dict:
    return tomllib.loads((REPO_ROOT / "blender_manifest.toml").read_text())


def build_wheel(out_dir: Path, blender_platform: str) -> Path:
    """The core and the Blender side as one wheel, written by hand: a wheel is a zip with
    METADATA, WHEEL and RECORD, and no build backend is needed (or reachable offline)."""
    version = manifest()["version"]
    tag = f"py3-none-{WHEEL_TAGS[blender_platform]}"
    path = out_dir / f"archhead-{version}-{tag}.whl"
    info = f"archhead-{version}.dist-info"
    files: dict[str, bytes] = {}
    for package in PACKAGES:
        for source in sorted((REPO_ROOT / package).rglob("*")):
            if source.is_file() and not any(s in str(source) for s in SKIP):
                files[source.relative_to(REPO_ROOT).as_posix()] = source.read_bytes()
    files[f"{info}/METADATA"] = (
        f"Metadata-Version: 2.1\nName: archhead\nVersion: {version}\nRequires-Python: >=3.11\n"
    ).encode()
    files[f"{info}/WHEEL"] = (
        f"Wheel-Version: 1.0\nGenerator: archhead build_extension\n"
        f"Root-Is-Purelib: false\nTag: {tag}\n"
    ).encode()
    record = [f"{name},sha256={_digest(data)},{len(data)}" for name, data in files.items()]
    files[f"{info}/RECORD"] = ("\n".join([*record, f"{info}/RECORD,,"]) + "\n").encode()
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as whl:
        for name, data in files.items():
            whl.writestr(name, data)
    return path


def _digest(data: bytes) -> str:
    return base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


def build(out_dir: Path, blender_platform: str | None = None) -> Path:
    """The extension zip for `blender_platform` (default: this machine's); returns its path."""
    blender_platform = blender_platform or this_platform()
    if blender_platform not in manifest().get("platforms", ()):
        raise SystemExit(f"{blender_platform} is not among the manifest's platforms")
    kernel = REPO_ROOT / "archhead_addon/splat/_build/libarchhead_splat.so"
    if blender_platform != this_platform() or not kernel.is_file():
        raise SystemExit(
            f"build on {blender_platform} after `make setup`: the zip carries "
            "the kernel compiled there"
        )
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="archhead_stage_") as tmp:
        stage = Path(tmp) / "archhead"
        stage.mkdir()
        for name in ADDON_FILES:
            source = REPO_ROOT / name
            if source.is_dir():
                shutil.copytree(source, stage / name, ignore=shutil.ignore_patterns(*SKIP[:1]))
            else:
                shutil.copy2(source, stage / name)
        (stage / "wheels").mkdir()
        wheel = build_wheel(stage / "wheels", blender_platform)
        text = (stage / "blender_manifest.toml").read_text()
        text = text.replace(
            "\n[permissions]", f'\nwheels = ["./wheels/{wheel.name}"]\n\n[permissions]', 1
        )
        (stage / "blender_manifest.toml").write_text(text)
        subprocess.run(
            [
                sys.executable,
                str(blender_ext_tool()),
                "build",
                "--source-dir",
                str(stage),
                "--output-dir",
                str(out_dir),
                "--split-platforms",
            ],
            check=True,
            capture_output=True,
            text=True,
        )
    name = f"archhead-{manifest()['version']}-{blender_platform.replace('-', '_')}.zip"
    return out_dir / name


def blender_ext_tool() -> Path:
    import bpy

    return Path(bpy.utils.system_resource("SCRIPTS")) / "addons_core/bl_pkg/cli/blender_ext.py"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "dist")
    args = parser.parse_args(argv)
    print(build(args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
