"""The demo: everything on the built-in head, from a synthetic subject to a rendered clip.

    python scripts/demo.py [--out DIR] [--checkpoint AVATAR.npz]           (the bpy module)
    blender -b --python-exit-code 1 --python scripts/demo.py -- [--out DIR] [--checkpoint CKPT]
    python -m archhead_addon demo [...]                                     (the same)

A thin wrapper: the demo is the installed module archhead_blender.demo (its docstring says
what it does; `python -m archhead_blender.demo` runs it from any folder). From here, a Python
without torch (Blender's own) trains with the checkout's .venv.
"""

import sys
from pathlib import Path

from archhead_blender import demo

REPO_ROOT = Path(__file__).resolve().parents[1]  # the checkout this script belongs to

if __name__ == "__main__":
    demo.main(sys.argv, fallback_python=str(REPO_ROOT / ".venv" / "bin" / "python"))
