"""Copy the UI suite's screenshots that the documentation shows into docs/ (`make
ui-screenshots` runs the suite first): the panel, the viewport at LOD 0 and 1, and the
decode and training progress states, as a Blender 4.3 window under Xvfb showed them."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
OUT = REPO / "out" / "ui"
# docs/ name -> the suite's screenshot (folder, name after its NN_ prefix)
SHOTS = {
    "ui_panel.png": ("scene_workflow", "panel_head.png"),
    "ui_lod0.png": ("scene_workflow", "viewport_lod0.png"),
    "ui_lod1.png": ("scene_workflow", "viewport_lod1.png"),
    "ui_decode_progress.png": ("scene_workflow", "decode_progress.png"),
    "ui_training_progress.png": ("training", "training_progress.png"),
    "ui_training_stopped.png": ("training", "training_stopped_avatar_loaded.png"),
}


def main() -> int:
    missing = []
    for target, (folder, name) in SHOTS.items():
        found = sorted((OUT / folder).glob(f"[0-9][0-9]_{name}"))
        if not found:
            missing.append(f"{folder}/{name}")
            continue
        shutil.copyfile(found[-1], REPO / "docs" / target)
        print(f"docs/{target} <- {found[-1].relative_to(REPO)}")
    if missing:
        print(f"missing (run make test-ui first): {', '.join(missing)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
