"""The package's shape as docs/ARCHITECTURE.md states it: imports go down the layers only, the
experiments form no import cycle, and the experiment table names every experiment."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import hamgrav
from hamgrav.experiments.base import Experiment
from hamgrav.experiments.registry import EXPERIMENTS, get_experiment

PACKAGE = Path(hamgrav.__file__).parent

#: top-level parts of the package, lowest first (docs/ARCHITECTURE.md)
LAYERS = [
    {"errors", "units", "files", "sizing", "__init__"},
    {"core"},
    {"bodies"},
    {"sim"},
    {"fit"},
    {"io"},
    {"report"},
    {"experiments"},
    {"cli"},
]


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        name = ".".join(("hamgrav", *parts))
        out[name.removesuffix(".__init__")] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Modules of the package that ``name`` imports, at module level or inside functions."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                candidate = f"{target}.{alias.name}"
                found.add(candidate if candidate in modules else target)
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
    return {target for target in found if target in modules and target != name}


def _layer(name: str) -> int:
    top = name.split(".")[1] if "." in name else "__init__"
    return next(i for i, layer in enumerate(LAYERS) if top in layer)


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def test_imports_go_down_the_layers_only(graph):
    upward = [
        f"{name} -> {target}"
        for name, targets in graph.items()
        for target in targets
        if name != "hamgrav" and _layer(target) > _layer(name)
    ]
    assert upward == []


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return out


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


@pytest.mark.parametrize("part", ["experiments", "report", "fit", "io", "sim"])
def test_no_import_cycle_within(graph, part):
    prefix = f"hamgrav.{part}"
    inside = {
        name: {t for t in targets if t.startswith(prefix)}
        for name, targets in graph.items()
        if name.startswith(prefix)
    }
    assert _cycles(inside) == []


def test_no_experiment_module_imports_the_runner(graph):
    importers = [
        name
        for name, targets in graph.items()
        if "hamgrav.experiments.runner" in targets and name.startswith("hamgrav.experiments.")
    ]
    assert importers == []


@pytest.mark.parametrize("name", sorted(EXPERIMENTS))
def test_every_table_entry_is_the_experiment_of_that_name(name):
    experiment = get_experiment(name)
    assert isinstance(experiment, Experiment)
    assert experiment.name == name


def test_every_experiment_module_is_in_the_table():
    listed = {entry.split(":")[0] for entry in EXPERIMENTS.values()}
    defining = {
        path.stem
        for path in (PACKAGE / "experiments").glob("*.py")
        if "(Experiment):" in path.read_text()
    }
    assert defining == listed


def _calls_of(path: Path) -> set[str]:
    """Names called as functions in the module at ``path`` (``Name(...)`` or ``x.Name(...)``)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call):
            f = node.func
            names.add(f.id if isinstance(f, ast.Name) else getattr(f, "attr", ""))
    return names


def test_no_experiment_builds_an_estimator_by_hand():
    # every row's estimator comes from experiments.common (row_estimator, fit_staged), so the
    # body, seed, mapper and cluster of a repetition reach every fit the same way
    builders = {"GravityEstimator"}
    offenders = {
        path.name
        for path in (PACKAGE / "experiments").glob("*.py")
        if path.name != "common.py" and _calls_of(path) & builders
    }
    assert not offenders
    assert "GravityEstimator" in _calls_of(PACKAGE / "experiments" / "common.py")


def test_report_modules_carry_no_paper_number_tables():
    # the paper's numbers are data of the experiment modules, passed to the report renderers
    for path in (PACKAGE / "report").glob("*.py"):
        tree = ast.parse(path.read_text())
        targets = [
            t
            for node in tree.body
            for t in (
                node.targets
                if isinstance(node, ast.Assign)
                else [node.target]
                if isinstance(node, ast.AnnAssign)
                else []
            )
        ]
        names = {t.id for t in targets if isinstance(t, ast.Name)}
        assert not {n for n in names if "paper" in n.lower()}, path.name
