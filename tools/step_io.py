"""Per cycle step: blackboard fields declared at 016c9ed (flat names, not enforced) and now (record.field, enforced).

.venv/bin/python tools/step_io.py > docs/figures/step_io_issue33_item2.json
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

BEFORE = "016c9ed"


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], capture_output=True, text=True, check=True).stdout


def declared_before() -> dict[str, dict[str, list[str]]]:
    out = {}
    for f in _git("ls-tree", "--name-only", BEFORE, "cellctl/supervisor/steps/").split():
        src = _git("show", f"{BEFORE}:{f}")
        for m in re.finditer(r'NAME = "(\w+)".*?READS = \(([^)]*)\).*?WRITES = \(([^)]*)\)', src, re.S):
            names = [re.findall(r'"(\w+)"', m.group(k)) for k in (2, 3)]
            out[m.group(1)] = {"reads": names[0], "writes": names[1]}
    return out


def main() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from cellctl.supervisor.steps import STEPS

    before = declared_before()
    rows = {}
    for name, s in STEPS.items():
        b = before.get(name, {"reads": [], "writes": []})
        rows[name] = {
            "before_reads": len(b["reads"]),
            "before_writes": len(b["writes"]),
            "reads": len(s.READS),
            "consults": len(set(s.CONSULTS)),
            "writes": len(s.WRITES),
        }
    out = {
        "what": __doc__.splitlines()[0],
        "command": ".venv/bin/python tools/step_io.py > docs/figures/step_io_issue33_item2.json",
        "steps": rows,
        "total_writes_before": sum(r["before_writes"] for r in rows.values()),
        "total_writes_after": sum(r["writes"] for r in rows.values()),
        "mypy_supervisor_steps_errors": {"before": 59, "after": 0, "command": ".venv/bin/python .ci/mypy_gate.py"},
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
