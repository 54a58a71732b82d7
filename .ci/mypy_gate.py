"""Type check gate run by `make typecheck` (and so by `make test` and CI).

mypy reads its settings from pyproject.toml ([tool.mypy]): the strict packages there must have no error;
the rest of the package keeps a checked-in count of errors per package (.ci/mypy_baseline.json) that may
only shrink. Counted per package, not per line, so moving code inside a package does not trip the gate.

    python .ci/mypy_gate.py            # check (exit 1 when a package has more errors than its baseline)
    python .ci/mypy_gate.py --update   # write the current counts (only ever lower them: see --allow-raise)
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from collections import Counter
from pathlib import Path

from mypy import api

ROOT = Path(__file__).resolve().parent.parent
BASELINE = ROOT / ".ci" / "mypy_baseline.json"
# Counted apart from their parent package: a strict subpackage of a package that is not strict yet.
OWN_KEYS = ("cellctl/planning/whole/",)
# The packages pyproject.toml holds to --strict's checks: no error, whatever the baseline says.
STRICT = ("cellctl/supervisor", "cellctl/bus", "cellctl/messages", "cellctl/planning/whole")
ERROR = re.compile(r"^(?P<path>[^:\s]+\.py):\d+(?::\d+)?: error: ")


def key_of(path: str) -> str:
    """The baseline key of a file: its top-level package (``cellctl/planning``) or module (``cellctl/images.py``)."""
    for own in OWN_KEYS:
        if path.startswith(own):
            return own.rstrip("/")
    parts = path.split("/")
    return "/".join(parts[:2])


def run_mypy() -> tuple[Counter[str], dict[str, list[str]], float]:
    t0 = time.perf_counter()
    out, err, _status = api.run([])  # files, cache and flags all come from pyproject.toml
    wall = time.perf_counter() - t0
    if err.strip():
        sys.exit(f"mypy failed to run:\n{err}")
    counts: Counter[str] = Counter()
    lines: dict[str, list[str]] = {}
    for line in out.splitlines():
        m = ERROR.match(line)
        if m:
            k = key_of(m["path"])
            counts[k] += 1
            lines.setdefault(k, []).append(line)
    return counts, lines, wall


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--update", action="store_true", help="write the current counts to the baseline")
    ap.add_argument(
        "--allow-raise", action="store_true", help="with --update: let a count go up (say why in the commit)"
    )
    args = ap.parse_args()

    counts, lines, wall = run_mypy()
    baseline: dict[str, int] = json.loads(BASELINE.read_text()) if BASELINE.exists() else {}
    baseline.update({k: 0 for k in STRICT})
    over = {k: n for k, n in counts.items() if n > baseline.get(k, 0)}
    under = {k: n for k, n in baseline.items() if counts.get(k, 0) < n}
    total = sum(counts.values())

    if args.update:
        if over and not args.allow_raise:
            print(f"refusing to raise the baseline for {sorted(over)}; fix the errors or pass --allow-raise")
            return 1
        BASELINE.write_text(json.dumps(dict(sorted(counts.items())), indent=1) + "\n")
        print(f"mypy baseline written: {total} errors in {len(counts)} packages ({wall:.1f} s)")
        return 0

    for k in sorted(over):
        print(f"{k}: {counts[k]} mypy errors, baseline {baseline.get(k, 0)}:")
        print("\n".join(f"  {line}" for line in lines[k]))
    if under:
        shrunk = ", ".join(f"{k} {baseline[k]} -> {counts.get(k, 0)}" for k in sorted(under))
        print(f"fewer mypy errors than the baseline ({shrunk}): lower it with `python .ci/mypy_gate.py --update`")
    if over:
        print("mypy: more errors than .ci/mypy_baseline.json allows (strict packages allow none); fix them")
        return 1
    print(f"mypy: {total} errors, none over the baseline ({wall:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
