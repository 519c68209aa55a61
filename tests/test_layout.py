"""The layout's rules, read from the code's own imports (ast): the core never reaches up into
the Blender side, operators never into panels, no cycle between top-level folders, the core
never imports bpy, the Blender side never imports torch, and nothing patches sys.path."""

import ast
import re
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("archhead_addon", "archhead_blender", "operators", "panels", "scripts", "benchmarks")
BLENDER_SIDE = ("archhead_blender", "operators", "panels")


def _imports(path: Path) -> set[str]:
    """Top-level names a file imports, relative imports resolved to their folder."""
    folder = path.relative_to(REPO_ROOT).parts[0]
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                names.add(node.module.split(".")[0])
            elif node.level == 1 or len(path.relative_to(REPO_ROOT).parts) > node.level:
                names.add(folder)
            else:  # `from ..x` out of a top-level folder: the add-on root's sibling x
                names.add((node.module or "").split(".")[0])
    return names


def _graph() -> dict[str, set[str]]:
    graph = {folder: set() for folder in FOLDERS}
    for folder in FOLDERS:
        for path in (REPO_ROOT / folder).rglob("*.py"):
            graph[folder] |= _imports(path) & set(FOLDERS) - {folder}
    return graph


def test_no_import_up_or_sideways():
    graph = _graph()
    assert not graph["archhead_addon"] & {
        "archhead_blender",
        "operators",
        "panels",
        "scripts",
        "benchmarks",
    }
    assert "panels" not in graph["operators"]
    assert not graph["archhead_blender"] & {"operators", "panels", "scripts", "benchmarks"}
    assert not graph["panels"] & {"operators", "scripts", "benchmarks"}


def test_no_cycle_between_top_level_folders():
    graph = _graph()

    def reaches(start, goal, seen=()):
        return any(
            n == goal or (n not in seen and reaches(n, goal, (*seen, n))) for n in graph[start]
        )

    assert [f for f in FOLDERS if reaches(f, f)] == []


def test_runtime_rules():
    for path in (REPO_ROOT / "archhead_addon").rglob("*.py"):
        assert "bpy" not in _imports(path), path
    for folder in BLENDER_SIDE:
        for path in (REPO_ROOT / folder).rglob("*.py"):
            assert "torch" not in _imports(path), path
    for folder in FOLDERS:
        for path in (REPO_ROOT / folder).rglob("*.py"):
            assert not re.search(r"sys\.path(\[|\.insert|\.append)", path.read_text()), path
