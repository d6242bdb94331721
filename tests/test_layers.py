"""The architecture's layers read one way: a package imports only packages before it.

Order from ../shared/DESIGN.md. ``errors``, ``configs``, ``files`` and ``threads`` are
the base every layer may use. Imports are read with ``ast``, including those inside functions.
"""

import ast
from pathlib import Path

import pytest

LAYERS = ("scenes", "simulation", "tasks", "rendering", "datasets", "metrics", "envs",
          "models", "perception", "policies", "training", "evaluation", "viz",
          "experiments", "cli")
BASE = {"errors", "configs", "files", "threads"}
ROOT = Path(__file__).resolve().parents[1] / "src" / "collavn"


def imported_packages(path: Path) -> list[tuple[str, int]]:
    """Top-level collavn packages ``path`` imports, with line numbers."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names: list[str] = []
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            parts = node.module.split(".")
            if parts[0] == "collavn":
                names = parts[1:2] if len(parts) > 1 else [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name.split(".")[1] for a in node.names
                     if a.name.startswith("collavn.")]
        out += [(n, node.lineno) for n in names]
    return out


def layer_violations(root: Path) -> list[str]:
    """``file:line: A imports B`` for every import against the layer order."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        own = rel.parts[0].removesuffix(".py")
        if own == "__init__" or own in BASE:
            allowed: set[str] = set(BASE)
        elif own not in LAYERS:
            bad.append(f"{rel}: package {own!r} is not in the layer order")
            continue
        else:
            allowed = BASE | set(LAYERS[:LAYERS.index(own) + 1])
        for name, line in imported_packages(path):
            if name not in allowed:
                bad.append(f"{rel}:{line}: {own} imports {name}")
    return bad


def test_every_import_follows_the_layer_order():
    assert layer_violations(ROOT) == []


def test_the_checker_catches_a_backward_import(tmp_path):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "bad.py").write_text(
        "def f():\n    from collavn.viz.topdown import save_scene_map\n")
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "ok.py").write_text("from collavn import errors\n"
                                               "import collavn.scenes.scene\n")
    (tmp_path / "gadgets.py").write_text("x = 1\n")
    assert layer_violations(tmp_path) == [
        "gadgets.py: package 'gadgets' is not in the layer order",
        "scenes/bad.py:2: scenes imports viz"]


@pytest.mark.parametrize("name", ["viz", "cli"])
def test_library_packages_never_import_the_cli_or_viz(name):
    users = sorted({str(p.relative_to(ROOT)) for p in ROOT.rglob("*.py")
                    for n, _ in imported_packages(p) if n == name
                    and p.relative_to(ROOT).parts[0] not in ("viz", "cli", "experiments")})
    assert users == []


def test_name_types_and_their_tables_agree():
    from typing import get_args

    from collavn.datasets.episode import DIFFICULTY_BINS, Difficulty
    from collavn.envs.config import DifficultyChoice
    from collavn.scenes.splits import SPLITS, Split
    from collavn.tasks import TASKS, TaskName

    assert get_args(TaskName) == tuple(TASKS)
    assert get_args(Difficulty) == tuple(DIFFICULTY_BINS)
    assert get_args(DifficultyChoice) == (*DIFFICULTY_BINS, "mixed")
    assert get_args(Split) == SPLITS == ("train", "val", "test")


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Package → the collavn packages it imports."""
    graph: dict[str, set[str]] = {}
    for path in root.rglob("*.py"):
        own = path.relative_to(root).parts[0].removesuffix(".py")
        graph.setdefault(own, set()).update(
            n for n, _ in imported_packages(path) if n != own)
    return graph


if __name__ == "__main__":  # `python tests/test_layers.py [SRC_DIR]`: print the graph
    import sys

    graph = import_graph(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT)
    for package in sorted(graph):
        print(f"{package:12s} -> {', '.join(sorted(graph[package])) or '-'}")
