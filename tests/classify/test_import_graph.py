"""The classify modules import each other without a cycle, at module level or inside functions.

A function-level import can hide a cycle (``synth`` ↔ ``_twin_source`` and ``evaluate`` ↔
``infer`` used to): the package imports fine until the two functions meet. The shared
vocabulary lives in leaf modules (:mod:`cellctl.classify.sample`, :mod:`cellctl.classify.decision`).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import cellctl.classify

PACKAGE = "cellctl.classify"
ROOT = Path(cellctl.classify.__file__).parent
MODULES = sorted(f"{PACKAGE}.{p.stem}" if p.stem != "__init__" else PACKAGE for p in ROOT.glob("*.py"))


def _imports(module: str) -> set[str]:
    """Every ``cellctl.classify`` module that ``module`` imports anywhere in its source."""
    path = ROOT / ("__init__.py" if module == PACKAGE else f"{module.rsplit('.', 1)[1]}.py")
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            # ``from cellctl.classify import x`` imports the submodule x when there is one
            names = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
        else:
            continue
        found |= {n for n in names if n in MODULES and n != module}
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


def test_no_import_cycle_between_classify_modules() -> None:
    graph = {m: _imports(m) for m in MODULES}
    assert graph[f"{PACKAGE}.synth"] >= {f"{PACKAGE}.sample", f"{PACKAGE}._twin_source"}
    assert f"{PACKAGE}.decision" in graph[f"{PACKAGE}.infer"] and f"{PACKAGE}.decision" in graph[f"{PACKAGE}.evaluate"]
    assert _cycles(graph) == []


def test_leaf_modules_import_no_other_classify_module() -> None:
    for leaf in ("sample", "decision"):
        assert _imports(f"{PACKAGE}.{leaf}") == set(), leaf


@pytest.mark.timeout(600)
def test_every_classify_module_imports_on_its_own_in_a_fresh_interpreter() -> None:
    procs = {
        m: subprocess.Popen(
            [sys.executable, "-c", f"import {m}"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        for m in MODULES
    }
    failed = {}
    for m, p in procs.items():
        _, err = p.communicate(timeout=300)
        if p.returncode != 0:
            failed[m] = err.strip().splitlines()[-1:]
    assert not failed, failed
