"""Tooling rules that ruff cannot state: a skip must mean "an optional package is absent", never "our code broke"."""

from __future__ import annotations

import ast
import re
from importlib import metadata
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _required_modules() -> set[str]:
    """Top-level modules shipped by the distributions cellctl requires (not its extras).

    Read from each distribution's file list: top_level.txt can be wrong (ur-rtde's names none of its modules).
    """
    modules = set()
    for req in metadata.requires("cellctl") or []:
        if "extra ==" in req:
            continue
        dist = metadata.distribution(re.split(r"[\s<>=!~;\[]", req, maxsplit=1)[0])
        for f in dist.files or []:
            top = f.parts[0]
            if not top.endswith((".dist-info", ".data")) and top != "..":
                modules.add(top.split(".")[0])  # an extension module reads "name.cpython-311-…so"
    return modules


def _importorskip_targets() -> list[tuple[str, str]]:
    found = []
    for path in sorted(TESTS.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == "importorskip"
                and node.args
                and isinstance(node.args[0], ast.Constant)
            ):
                found.append((f"{path.relative_to(TESTS)}:{node.lineno}", str(node.args[0].value)))
    return found


def test_importorskip_only_for_optional_third_party_packages() -> None:
    """A broken import of our own module, or of a required dependency, must fail the test, not skip it."""
    required = _required_modules()
    bad = [
        f"{where} skips on {module!r}"
        for where, module in _importorskip_targets()
        if module.split(".")[0] == "cellctl" or module.split(".")[0] in required
    ]
    assert not bad, "importorskip on a module that is always installed: " + "; ".join(bad)
