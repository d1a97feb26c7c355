"""The packages stack in floors and no import runs upward (see docs/design.md, "Layers").

Every import in the project's own code, at module level or inside a function, is read from
the source with ``ast`` and checked against the floor of the importing package: a module may
import its own package and any package on a lower floor, nothing else. Two packages on the
same floor (``stages`` and ``synth``) are independent of each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent

# package -> floor; a module may import packages whose floor is lower than its own.
FLOORS = {
    "core": 0,       # shared types: packets, config, errors
    "stages": 1,     # one module per stage or sink
    "synth": 1,      # the scene generator (independent of the stages)
    "heightnet": 2,  # training, export and evaluation of the height network
    "pipeline": 3,   # orchestration and the command line
    "bench": 4,      # benchmarks, which may drive everything
}


def imported_packages(path: Path) -> set[tuple[str, int]]:
    """(top-level project package, line) for every import statement in one file."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            top = name.split(".")[0]
            if top in FLOORS:
                found.add((top, node.lineno))
    return found


def upward_imports(package: str) -> list[str]:
    floor = FLOORS[package]
    wrong = []
    for path in sorted((REPO_ROOT / package).rglob("*.py")):
        for imported, line in sorted(imported_packages(path)):
            if imported != package and FLOORS[imported] >= floor:
                wrong.append(f"{path.relative_to(REPO_ROOT)}:{line} imports {imported} "
                             f"(floor {FLOORS[imported]}, its own floor is {floor})")
    return wrong


@pytest.mark.parametrize("package", sorted(FLOORS))
def test_no_package_imports_a_higher_or_sibling_floor(package):
    assert (REPO_ROOT / package / "__init__.py").exists()
    assert upward_imports(package) == []


def test_every_project_package_has_a_floor():
    # A new top-level package must be given a floor here (and in docs/design.md).
    packages = {p.parent.name for p in REPO_ROOT.glob("*/__init__.py")}
    assert packages == set(FLOORS)


def test_the_check_sees_an_upward_import(tmp_path):
    # The checker itself: a stage importing orchestration, even inside a function, is caught.
    source = tmp_path / "stage.py"
    source.write_text("import numpy\nfrom core.packets import Frame\n\n"
                      "def f():\n    from pipeline.runner import run_pipeline\n")
    assert imported_packages(source) == {("core", 2), ("pipeline", 5)}
