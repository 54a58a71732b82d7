"""The longest modules and functions of a package (issue 33: no module over 800 lines, no function over 150).

Usage::

    .venv/bin/python tools/code_sizes.py                 # cellctl/ of this checkout, top 10
    .venv/bin/python tools/code_sizes.py --root DIR -n 20 --json

A function's length is its ``def`` line (decorators excluded) to its last line, nested functions
included in their parent's length and also counted on their own.
"""

from __future__ import annotations

import argparse
import ast
import json
from pathlib import Path


def sizes(root: Path) -> tuple[list[tuple[int, str]], list[tuple[int, str]]]:
    """``(modules, functions)``: (lines, name) each, longest first."""
    mods, funcs = [], []
    for p in sorted(root.rglob("*.py")):
        rel = p.relative_to(root.parent).as_posix()
        text = p.read_text(encoding="utf-8")
        mods.append((len(text.splitlines()), rel))
        tree = ast.parse(text, rel)

        def walk(node: ast.AST, prefix: str, rel: str = rel) -> None:
            for ch in ast.iter_child_nodes(node):
                if isinstance(ch, ast.FunctionDef | ast.AsyncFunctionDef):
                    name = f"{prefix}{ch.name}"
                    funcs.append((ch.end_lineno - ch.lineno + 1, f"{rel}::{name}"))  # type: ignore[operator]
                    walk(ch, name + ".", rel)
                elif isinstance(ch, ast.ClassDef):
                    walk(ch, f"{prefix}{ch.name}.", rel)
                else:
                    walk(ch, prefix, rel)

        walk(tree, "")
    return sorted(mods, reverse=True), sorted(funcs, reverse=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parent.parent / "cellctl")
    ap.add_argument("-n", type=int, default=10)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    mods, funcs = sizes(a.root)
    if a.json:
        print(json.dumps({"modules": mods[: a.n], "functions": funcs[: a.n]}, indent=1))
        return 0
    big_m, big_f = sum(n > 800 for n, _ in mods), sum(n > 150 for n, _ in funcs)
    print(f"modules over 800 lines: {big_m}; functions over 150: {big_f}")
    print("longest modules:")
    for n, name in mods[: a.n]:
        print(f"  {n:5d}  {name}")
    print("longest functions:")
    for n, name in funcs[: a.n]:
        print(f"  {n:5d}  {name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
