"""docs/architecture.md's "where to change what" map names only files and folders that exist (issue 33 item 7).

A module that moves or is split leaves the map pointing at nothing; a newcomer following the map
then opens the wrong place. Every path under ``cellctl/`` the map spells in backticks is checked
(``{a,b}`` alternatives expanded; a ``<placeholder>`` checks the folder before it).
"""

from __future__ import annotations

import re

from cellctl.config import project_root

ROOT = project_root()
PATH = re.compile(r"(?:^|[\s(])(cellctl/(?:\{[^}]*\}|[^\s`,;:(){}])*)")


def _expand(path: str) -> list[str]:
    m = re.search(r"\{([^}]*)\}", path)
    if m is None:
        return [path]
    return [p for alt in m.group(1).split(",") for p in _expand(path[: m.start()] + alt + path[m.end() :])]


def _map_paths() -> list[str]:
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text.split("## 0. Where to change what", 1)[1].split("\n## ", 1)[0]
    paths = []
    for code in re.findall(r"`([^`]*)`", section):
        for m in PATH.finditer(code):
            paths.extend(_expand(m.group(1).split("::")[0]))
    return paths


def test_every_cellctl_path_in_the_map_exists() -> None:
    paths = _map_paths()
    assert len(paths) > 40, f"the map parser found only {len(paths)} paths: has the section's title changed?"
    missing = [p for p in paths if not (ROOT / p.split("<", 1)[0]).exists()]
    assert missing == [], f"docs/architecture.md section 0 names paths that do not exist: {missing}"
