"""cellctl's modules import each other without a cycle, at module level or inside functions.

A function-level import can hide a cycle (classify ``synth`` ↔ ``_twin_source`` and ``evaluate`` ↔
``infer`` used to; ``bus.security`` → the OPC UA gateway → ``bus.session`` → ``bus.security`` did):
the package imports fine until the two functions meet. Shared vocabulary lives in leaf modules
(:mod:`cellctl.classify.sample`, :mod:`cellctl.classify.decision`, :mod:`cellctl.surface`, …).
Imports under ``if TYPE_CHECKING:`` never run and are not edges.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import cellctl

ROOT = Path(cellctl.__file__).parent
MODULES = {
    ".".join(("cellctl", *p.relative_to(ROOT).with_suffix("").parts)).removesuffix(".__init__"): p
    for p in ROOT.rglob("*.py")
}
CLASSIFY = "cellctl.classify"


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip |= {id(n) for n in ast.walk(node)}
    return skip


def _imports(module: str) -> set[str]:
    """Every cellctl module that ``module`` imports anywhere in its source (outside TYPE_CHECKING)."""
    path = MODULES[module]
    tree = ast.parse(path.read_text(), str(path))
    skip = _type_checking_nodes(tree)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module != "__future__":
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            # ``from pkg import x`` imports the submodule x when there is one
            names = [base, *(f"{base}.{a.name}" for a in node.names)]
        else:
            continue
        # a module importing its own parent package is not an edge of interest (the parent runs first anyway)
        found |= {n for n in names if n in MODULES and n != module and not module.startswith(n + ".")}
    return found


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph`` (each a path that returns to its start)."""
    cycles: list[list[str]] = []
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycles.append([*path[path.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return cycles


def test_the_cycle_finder_finds_a_cycle_hidden_in_a_function() -> None:
    """The check itself: a two-module cycle through a function-level import is reported."""
    tree = ast.parse("import numpy\n\ndef f():\n    from cellctl.classify.infer import SurfaceModel\n")
    names = {a.module for a in ast.walk(tree) if isinstance(a, ast.ImportFrom)}
    assert names == {"cellctl.classify.infer"}
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c", "a"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_in_the_package() -> None:
    graph = {m: _imports(m) for m in MODULES}
    assert graph[f"{CLASSIFY}.synth"] >= {f"{CLASSIFY}.sample", f"{CLASSIFY}._twin_source"}
    assert (
        f"{CLASSIFY}.decision" in graph[f"{CLASSIFY}.infer"] and f"{CLASSIFY}.decision" in graph[f"{CLASSIFY}.evaluate"]
    )
    assert _cycles(graph) == []


def test_leaf_modules_import_no_other_classify_module() -> None:
    for leaf in ("sample", "decision"):
        assert not {m for m in _imports(f"{CLASSIFY}.{leaf}") if m.startswith(CLASSIFY)}, leaf


@pytest.mark.timeout(600)
def test_every_classify_module_imports_on_its_own_in_a_fresh_interpreter() -> None:
    procs = {
        m: subprocess.Popen(
            [sys.executable, "-c", f"import {m}"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        for m in sorted(MODULES)
        if m == CLASSIFY or m.startswith(CLASSIFY + ".")
    }
    failed = {}
    for m, p in procs.items():
        _, err = p.communicate(timeout=300)
        if p.returncode != 0:
            failed[m] = err.strip().splitlines()[-1:]
    assert not failed, failed
