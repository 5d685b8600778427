"""The floors of the package (docs/architecture.md): every import points down, and no two
modules import each other.

Every ``import`` and ``from ... import`` statement of every module under ``fmu_greybox/`` is
read from its syntax tree: at module level, inside functions and methods, under
``if TYPE_CHECKING:`` and in ``try`` blocks alike (``ast.walk`` visits them all). Relative
imports are resolved against the importing module. Not read: the lazy public API of
``fmu_greybox/__init__.py`` and the Python FMU's runtime loader (``export/runtime.py``), which
load modules by name with ``importlib`` at run time.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "fmu_greybox"
#: Compiled modules of the package (no Python source to read).
EXTENSIONS = ("fmu_greybox._chainstep",)

#: The floors, bottom first: a module may import its own floor and the floors below it.
#: A floor is a subpackage, except the first (the package's own modules, the compiled chain
#: step and the package itself) and the last (the command line).
FLOORS: tuple[tuple[str, ...], ...] = (
    (
        "fmu_greybox",
        "fmu_greybox.errors",
        "fmu_greybox.atomic",
        "fmu_greybox.units",
        "fmu_greybox.suggest",
        "fmu_greybox.progress",
        "fmu_greybox.resources",
        "fmu_greybox.side_by_side",
        "fmu_greybox._chainstep",
    ),
    ("fmu_greybox.data",),
    ("fmu_greybox.gp",),
    ("fmu_greybox.fmi",),
    ("fmu_greybox.project",),
    ("fmu_greybox.model",),
    ("fmu_greybox.synth",),
    ("fmu_greybox.evidence",),
    ("fmu_greybox.workflow",),
    ("fmu_greybox.diagnosis",),
    ("fmu_greybox.export",),
    ("fmu_greybox.report",),
    ("fmu_greybox.campaign",),
    ("fmu_greybox.cli",),
)

#: Pairs of modules allowed to import each other, each with why. Both modules are being
#: changed on the issue-43 branches (model exchange, win64): ``export.fmu`` imports
#: ``package_native`` inside ``export_greybox``, and ``export.native`` imports ``ExportPlan``
#: (type hints) and ``check_valid`` (inside ``package_native``) from ``export.fmu``.
#: The mend, once those branches are merged: move ``ExportPlan``, ``check_valid`` and the
#: model-description fixes they use out of ``export/fmu.py`` into a module both import.
ALLOWED_CYCLES: dict[frozenset[str], str] = {
    frozenset({"fmu_greybox.export.fmu", "fmu_greybox.export.native"}): (
        "export/fmu.py and export/native.py are being changed by the issue-43 branches"
    ),
}


def module_name(path: Path) -> str:
    """``fmu_greybox/model/chain.py`` -> ``fmu_greybox.model.chain`` (a package: its folder)."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    """Every Python module of the package, by dotted name."""
    return {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def imported_names(path: Path, known: set[str]) -> Iterator[tuple[int, str]]:
    """(line, module) of every import of a ``fmu_greybox`` module in ``path``, at any depth.

    ``from fmu_greybox.x import y`` names ``fmu_greybox.x.y`` when that is a module of the
    package, else ``fmu_greybox.x``; relative imports are resolved first.
    """
    own = module_name(path).split(".")
    package = own if path.name == "__init__.py" else own[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            parent = ".".join(base + ([node.module] if node.module else []))
            targets = [
                f"{parent}.{alias.name}" if f"{parent}.{alias.name}" in known else parent
                for alias in node.names
            ]
        else:
            continue
        for target in targets:
            if target == "fmu_greybox" or target.startswith("fmu_greybox."):
                yield node.lineno, target


def floor_of(name: str) -> int:
    """Index in :data:`FLOORS` of the floor a dotted module name lives on."""
    for index, floor in enumerate(FLOORS):
        for place in floor:
            if name == place or (place != "fmu_greybox" and name.startswith(place + ".")):
                return index
    raise LookupError(f"{name} is on no floor: place it in FLOORS and docs/architecture.md")


def import_graph(found: dict[str, Path]) -> dict[str, dict[str, int]]:
    """Module -> {imported module: first line}, every import of the package included."""
    known = {*found, *EXTENSIONS}
    graph: dict[str, dict[str, int]] = {}
    for name, path in found.items():
        edges = graph.setdefault(name, {})
        for line, target in imported_names(path, known):
            while target not in known and "." in target:  # a name taken from a module
                target = target.rpartition(".")[0]
            if target != name:
                edges.setdefault(target, line)
    return graph


def upward_imports(found: dict[str, Path]) -> list[str]:
    """Every import of a module from a floor above the importer's, in words."""
    floors = [" / ".join(floor) for floor in FLOORS]
    upward = []
    for name, edges in import_graph(found).items():
        for target, line in edges.items():
            if floor_of(target) > floor_of(name):
                upward.append(
                    f"{found[name].relative_to(PACKAGE.parent)}:{line} imports {target} "
                    f"(floor {floors[floor_of(target)]} above {floors[floor_of(name)]})"
                )
    return upward


def cycles(graph: dict[str, dict[str, int]]) -> list[frozenset[str]]:
    """The strongly connected sets of two or more modules (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[frozenset[str]] = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph[root]))]
        index[root] = low[root] = len(index)
        stack.append(root)
        while work:
            node, children = work[-1]
            child = next((c for c in children if c in graph), None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    members = stack[stack.index(node) :]
                    del stack[stack.index(node) :]
                    if len(members) > 1:
                        found.append(frozenset(members))
            elif child not in index:
                index[child] = low[child] = len(index)
                stack.append(child)
                work.append((child, iter(graph[child])))
            elif child in stack:
                low[node] = min(low[node], index[child])
    return found


def test_every_module_is_on_a_floor() -> None:
    unplaced = []
    for name in [*modules(), *EXTENSIONS]:
        try:
            floor_of(name)
        except LookupError as error:
            unplaced.append(str(error))
    assert not unplaced, "\n".join(unplaced)


def test_every_import_points_down() -> None:
    upward = upward_imports(modules())
    assert not upward, f"{len(upward)} import(s) against the floors:\n" + "\n".join(upward)


def test_no_modules_import_each_other_beyond_the_allowed() -> None:
    found = cycles(import_graph(modules()))
    for pair, why in ALLOWED_CYCLES.items():
        print(f"allowed cycle: {' <-> '.join(sorted(pair))}: {why}")
    unexpected = [sorted(c) for c in found if c not in ALLOWED_CYCLES]
    assert not unexpected, "modules that import each other: " + "; ".join(map(str, unexpected))
    gone = [sorted(pair) for pair in ALLOWED_CYCLES if pair not in found]
    assert not gone, f"no longer a cycle, remove from ALLOWED_CYCLES: {gone}"


@pytest.mark.parametrize(
    ("source", "importer", "expected"),
    [
        ("from fmu_greybox.report.main import write_report\n", "model/x.py", "report"),
        ("def f():\n    from ..report import main\n", "model/x.py", "report"),
        (
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
            "    from fmu_greybox.workflow.train import train_model\n",
            "gp/x.py",
            "workflow",
        ),
    ],
)
def test_an_upward_import_anywhere_in_a_module_is_found(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, source: str, importer: str, expected: str
) -> None:
    """The walk sees module-level, function-level, relative and TYPE_CHECKING imports."""
    fake = tmp_path / "fmu_greybox"
    for name in ("model", "gp", "report", "workflow"):
        (fake / name).mkdir(parents=True)
        (fake / name / "__init__.py").write_text("")
    (fake / "__init__.py").write_text("")
    (fake / "report" / "main.py").write_text("def write_report():\n    pass\n")
    (fake / "workflow" / "train.py").write_text("def train_model():\n    pass\n")
    (fake / importer).write_text(source)
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    upward = upward_imports(modules())
    assert len(upward) == 1 and f"fmu_greybox.{expected}" in upward[0], upward
