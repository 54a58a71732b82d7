"""The runtime imports nothing of the measurement harness (issue 33 item 5).

``cellctl/bench/`` (benches, reliability runs, the demo's stories) measures the runtime through its
public functions and its wire contract; only ``cellctl.cli`` (the ``cellctl bench``/``demo`` commands) and
the harness itself may import it. A runtime module that needs a bench helper is a sign the helper is
runtime code: move it to the runtime side. Checked on the source with ``ast``, so a function-level
import, an import under ``TYPE_CHECKING`` and ``importlib.import_module("cellctl.bench…")`` all count.
"""

from __future__ import annotations

import ast
from pathlib import Path

import cellctl

ROOT = Path(cellctl.__file__).parent
HARNESS = "cellctl.bench"
ALLOWED = ("cellctl.bench", "cellctl.cli")  # the harness itself and the command line that runs it


def _module_name(path: Path) -> str:
    return ".".join(("cellctl", *path.relative_to(ROOT).with_suffix("").parts)).removesuffix(".__init__")


def _is_harness(name: str) -> bool:
    return name == HARNESS or name.startswith(HARNESS + ".")


def harness_imports(source: str, module: str, is_package: bool = False) -> list[str]:
    """The harness modules that ``source`` (the text of ``module``) imports anywhere, with their line."""
    tree = ast.parse(source)
    package = module if is_package else module.rpartition(".")[0]
    found: list[str] = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module != "__future__":
            base = node.module or ""
            if node.level:  # relative: resolve against the importing module's package
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + ([node.module] if node.module else []))
            names = [base, *(f"{base}.{a.name}" for a in node.names)]
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, (ast.Attribute, ast.Name))
            and (node.func.attr if isinstance(node.func, ast.Attribute) else node.func.id) == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            names = [node.args[0].value]
        hits = sorted({n for n in names if _is_harness(n)})
        if hits:
            found.append(f"{module}:{node.lineno}: {hits[0]}")
    return found


def test_the_check_finds_a_planted_harness_import() -> None:
    """The check itself: module-level, function-level, relative and importlib imports are all found."""
    planted = (
        "import numpy\n"
        "from cellctl.bench.options import BenchOptions\n"
        "def f():\n    import cellctl.bench.pose\n"
        "def g():\n    from ..bench import wash\n"
        "def h():\n    importlib.import_module('cellctl.bench.bus')\n"
    )
    found = harness_imports(planted, "cellctl.washing.plan")
    assert [f.split(":")[1] for f in found] == ["2", "4", "6", "8"], found
    assert harness_imports("from cellctl.benchmarks import x\nimport cellctl.bus\n", "cellctl.washing.plan") == []


def test_no_runtime_module_imports_the_harness() -> None:
    offenders = []
    for path in sorted(ROOT.rglob("*.py")):
        module = _module_name(path)
        if any(module == a or module.startswith(a + ".") for a in ALLOWED):
            continue
        offenders += harness_imports(path.read_text(encoding="utf-8"), module, path.name == "__init__.py")
    assert offenders == [], f"runtime modules import the measurement harness (move the helper): {offenders}"
