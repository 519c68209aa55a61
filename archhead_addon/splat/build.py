"""Build the C++ splat kernel into a shared library.

Two places hold it. `python -m archhead_addon.splat.build` (the `make setup` target runs it)
builds inside the package, for a checkout. Where that library is missing or older than the
sources (an installed Blender extension ships sources, not a binary built on another
platform), `ensure_library` compiles it on first use into the user's cache
(`$ARCHHEAD_CACHE/kernel/<hash>/`), keyed by the sources, flags and compiler, so reinstalling
the extension neither wipes it nor keeps a stale one. Builds are idempotent and atomic (a
process with the old library loaded keeps a valid file). Standard library only, so
Blender's Python can run it too.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from ..paths import cache_dir

SOURCE_DIR = Path(__file__).resolve().parent / "csrc"
BUILD_DIR = Path(__file__).resolve().parent / "_build"
LIB_NAME = "libarchhead_splat.dylib" if sys.platform == "darwin" else "libarchhead_splat.so"
LIB_PATH = BUILD_DIR / LIB_NAME
STAMP_PATH = BUILD_DIR / (LIB_NAME + ".sha256")

# No -march=native (the library must run on any x86-64; the hot loops carry AVX2 and
# AVX-512 versions chosen at run time, csrc/dispatch.hpp) and no -ffast-math (it breaks the
# NaN guards and the bitwise determinism). -ffp-contract=off leaves the fused operations to
# the source, which writes the same ones in the AVX2 and AVX-512 versions, so that their
# images are bitwise identical. -Wno-psabi:
# vectors passed between the hot loops' helpers, all in one translation unit, draw notes
# about compatibility with code compiled for other instruction sets.
FLAGS = [
    "-std=c++17", "-O3", "-fopenmp", "-shared", "-fPIC", "-ffp-contract=off", "-Wall",
    "-Wno-psabi",
]  # fmt: skip
COMPILERS = ("g++", "c++", "clang++")

INSTALL_HINT = (
    "Install a C++17 compiler with OpenMP (the kernel is then compiled on first use; in a "
    "checkout `make setup` builds it): Debian/Ubuntu `sudo apt install g++`, "
    "Fedora `sudo dnf install gcc-c++`, macOS `brew install gcc` (and set CXX=g++-14 or "
    "the installed version)."
)


class BuildError(RuntimeError):
    """The kernel could not be compiled; the message says why and what to do."""


def sources() -> list[Path]:
    return sorted(p for p in SOURCE_DIR.iterdir() if p.suffix in {".h", ".hpp", ".cpp"})


def source_hash(compiler: str = "") -> str:
    h = hashlib.sha256()
    for path in sources():
        h.update(path.name.encode())
        h.update(path.read_bytes())
    h.update(" ".join(FLAGS).encode())
    h.update(compiler.encode())
    return h.hexdigest()


def find_compiler(env: dict[str, str] | None = None) -> str:
    """The compiler to use: $CXX if set, else the first of g++, c++, clang++ on PATH."""
    env = os.environ if env is None else env
    path = env.get("PATH", "")
    candidates = [env["CXX"]] if env.get("CXX") else list(COMPILERS)
    for name in candidates:
        found = shutil.which(name, path=path)
        if found:
            return found
    raise BuildError(f"No C++ compiler found (looked for {', '.join(candidates)}). {INSTALL_HINT}")


def is_current(compiler: str | None = None) -> bool:
    """Whether the built library matches the sources (and, if given, the compiler)."""
    if not (LIB_PATH.exists() and STAMP_PATH.exists()):
        return False
    stamp = STAMP_PATH.read_text().split()
    if compiler is None:
        return len(stamp) == 2 and stamp[1] == source_hash(stamp[0])
    return stamp == [compiler, source_hash(compiler)]


def cache_lib_path(compiler: str) -> Path:
    """Where `ensure_library` keeps the kernel built with `compiler` for these sources."""
    return cache_dir() / "kernel" / source_hash(compiler)[:16] / LIB_NAME


def _package_library_usable() -> bool:
    """The package's own build is current, or there are no sources to compare it with."""
    return is_current() or (LIB_PATH.exists() and not SOURCE_DIR.exists())


def ensure_library(verbose: bool = True) -> Path:
    """The library for the current sources: the package's when current, else the cache's,
    compiled there on first use. Raises BuildError (what to install) without a compiler."""
    if _package_library_usable():
        return LIB_PATH
    compiler = find_compiler()
    path = cache_lib_path(compiler)
    if not path.exists():
        if verbose:
            print(
                f"archhead: compiling the splat kernel (first use) into {path.parent}",
                file=sys.stderr,
                flush=True,
            )
        _compile(compiler, path, verbose=False)
    return path


def unavailable_reason() -> str | None:
    """None when the kernel is built for these sources or can be compiled on first use, else
    why not (without compiling anything: Blender asks this while it starts)."""
    if _package_library_usable():
        return None
    try:
        path = cache_lib_path(find_compiler())
    except BuildError as exc:
        return str(exc)
    return None if path.exists() or SOURCE_DIR.exists() else f"no kernel sources at {SOURCE_DIR}"


def build(force: bool = False, verbose: bool = False) -> Path:
    """Compile the kernel inside the package if needed and return the library path."""
    compiler = find_compiler()
    if not force and is_current(compiler):
        return LIB_PATH
    _compile(compiler, LIB_PATH, verbose)
    STAMP_PATH.write_text(f"{compiler} {source_hash(compiler)}\n")
    return LIB_PATH


def _compile(compiler: str, lib_path: Path, verbose: bool) -> None:
    lib_path.parent.mkdir(parents=True, exist_ok=True)
    # Compile to a temporary name and rename, so a process that has the old library
    # loaded keeps a valid file.
    fd, tmp = tempfile.mkstemp(dir=lib_path.parent, suffix=lib_path.suffix)
    os.close(fd)
    cmd = [compiler, *FLAGS, str(SOURCE_DIR / "splat.cpp"), "-o", tmp]
    if verbose:
        print(" ".join(cmd))
    try:
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode != 0:
            raise BuildError(
                f"Compiling the splat kernel failed ({' '.join(cmd)}):\n{result.stderr}\n"
                "If the error mentions omp.h or -fopenmp, the compiler lacks OpenMP. "
                + INSTALL_HINT
            )
        os.replace(tmp, lib_path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m archhead_addon.splat.build",
        description="Compile the CPU splat kernel (C++/OpenMP) into the package, once: later "
        "calls reuse it while its sources are unchanged.",
    )
    parser.add_argument("--force", action="store_true", help="rebuild even when up to date")
    parser.add_argument("-v", "--verbose", action="store_true", help="print the compiler call")
    args = parser.parse_args(argv)
    try:
        path = build(force=args.force, verbose=args.verbose)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"splat kernel: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
