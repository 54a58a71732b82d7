"""``cellctl audit verify`` (check the index hash chain and every cycle log) and ``cellctl audit head``.

Exit codes of ``verify``: 0 intact, 1 something was found, 2 usage error (e.g. no index).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from cellctl.cli import add_config_arguments, config_from_args

# Below this many rows the audit takes well under a second; progress would only be noise.
_PROGRESS_MIN_ROWS = 200
_PROGRESS_PERIOD_S = 2.0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("audit", help="verify the cycle index hash chain and the cycle logs, or print the chain head")
    verbs = p.add_subparsers(dest="audit_verb", metavar="ACTION", required=True)

    v = verbs.add_parser("verify", help="exit 0 if every record and log is intact, 1 if anything was found")
    v.add_argument("--json", action="store_true", help="print the report as JSON")
    v.add_argument(
        "--head", default=None, metavar="HASH", help="a row hash exported earlier (audit head); it must be in the chain"
    )
    add_config_arguments(v)
    v.set_defaults(func=run_verify)

    h = verbs.add_parser("head", help="print the newest row hash and its seq (export it to the MES/PLC)")
    h.add_argument("--json", action="store_true")
    add_config_arguments(h)
    h.set_defaults(func=run_head)


class _Progress:
    """Rows hashed so far on stderr, at most every few seconds, for large indexes."""

    def __init__(self) -> None:
        self._next = time.monotonic() + _PROGRESS_PERIOD_S

    def __call__(self, done: int, total: int) -> None:
        if total < _PROGRESS_MIN_ROWS or (done < total and time.monotonic() < self._next):
            return
        self._next = time.monotonic() + _PROGRESS_PERIOD_S
        print(f"audit: {done}/{total} rows checked", file=sys.stderr)


def run_verify(args: argparse.Namespace) -> int:
    from cellctl.recording.audit import verify_audit
    from cellctl.recording.references import reference_root

    cfg = config_from_args(args)
    report = verify_audit(
        cfg.path(cfg.recording.index),
        cfg.path(cfg.recording.dir),
        args.head,
        progress=_Progress(),
        references=reference_root(cfg),
    )
    if args.json:
        print(json.dumps(report.as_dict(), indent=1))
    else:
        for f in report.findings:
            print(f"{f.severity.value.upper():6} {f.kind.value}: {f.message}")
        verdict = "intact" if report.ok else f"{len(report.tampering)} finding(s) point at tampering"
        print(
            f"audit: {report.rows} rows, {report.logs_checked} logs checked, head seq {report.head_seq}"
            f" {report.head_hash}: {verdict}"
        )
    return 0 if report.ok else 1


def run_head(args: argparse.Namespace) -> int:
    from cellctl.recording.audit import read_head
    from cellctl.recording.index import GENESIS

    cfg = config_from_args(args)
    row = read_head(cfg.path(cfg.recording.index))
    head = {"seq": row.seq if row else 0, "row_hash": row.row_hash if row else GENESIS}
    head["cycle_id"] = row.cycle_id if row else None
    from cellctl.review.ledger import LEDGER_NAME, Ledger

    # the review ledger's head too: deleting the newest decisions is found against an exported one
    head["reviews"] = Ledger(cfg.path(cfg.recording.dir) / LEDGER_NAME).head()
    print(json.dumps(head) if args.json else f"{head['row_hash']} {head['seq']}")
    return 0
