"""Plan files and the plan cache in ``models/plans/`` (ARCHITECTURE §6).

A plan file is JSON: ``{"format": "cellctl-plan/1", "sha256": <hex of the canonical body>,
"plan": {...}}``, the body being :meth:`cellctl.planning.plan.Plan.to_json`. Writes go to a
temporary file in the same folder, are fsynced and renamed over the target, so a reader (or
a crash) never sees half a plan. A file whose hash does not match, that is not JSON, or has
the wrong format is *damaged*; one that is intact but whose body is not a plan
(:meth:`~cellctl.planning.plan.Plan.from_json` refuses it) or is a plan of another bin type
or surface is *foreign*. Lookups skip both (cache miss with the reason), they never crash.

Two levels: :func:`write_document`/:func:`read_document` handle the hashed envelope around
any JSON object (the planner worker's job records use them too); :func:`write_plan`/
:func:`read_plan` put a typed :class:`~cellctl.planning.plan.Plan` in it. Light module:
json/hashlib/numpy only, the supervisor may import it.

Layout: ``<plans_dir>/<bin_type>/<surface>/<plan_id>.json``; the newest plan whose base pose
is closest to the measured one wins.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import stat
import tempfile
from pathlib import Path
from typing import Any

from cellctl.errors import PlanCacheError
from cellctl.planning.plan import Plan

__all__ = [
    "FORMAT",
    "MAX_PLAN_BYTES",
    "check_plan",
    "list_plans",
    "plan_path",
    "read_document",
    "read_plan",
    "write_document",
    "write_plan",
]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

FORMAT = "cellctl-plan/1"

MAX_PLAN_BYTES = 32 * 1024 * 1024
"""Largest plan file read (a fast-mode plan is ~100 kB); anything bigger is not one of ours."""


def _canonical(body: dict[str, Any]) -> bytes:
    return json.dumps(body, sort_keys=True, separators=(",", ":")).encode()


def plan_path(plans_dir: Path | str, plan: Plan) -> Path:
    """Where ``plan`` lives in the cache."""
    return Path(plans_dir) / _safe(plan.bin_type) / _safe(plan.surface) / f"{_safe(plan.plan_id)}.json"


def _safe(name: str) -> str:
    s = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(name))
    if not s or s.startswith("."):
        raise PlanCacheError(f"name {name!r} cannot be used in a plan path; expected letters, digits, '-', '_'")
    return s


def write_plan(plan: Plan, path: Path | str) -> Path:
    """Atomically write ``plan`` to ``path`` (temp file + fsync + rename).

    Raises:
        PlanCacheError: the folder cannot be created or the file written.
    """
    return write_document(plan.to_json(), path)


def write_document(body: dict[str, Any], path: Path | str) -> Path:
    """Atomically write any JSON object in the hashed ``cellctl-plan/1`` envelope.

    Raises:
        PlanCacheError: the folder cannot be created or the file written.
    """
    p = Path(path)
    doc = {"format": FORMAT, "sha256": hashlib.sha256(_canonical(body)).hexdigest(), "plan": body}
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
        try:
            with os.fdopen(fd, "w") as f:
                json.dump(doc, f, separators=(",", ":"))
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o644)  # mkstemp makes 0600; plans are shared with other workers/users
            os.replace(tmp, p)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError as err:
        raise PlanCacheError(f"cannot write plan file {str(p)!r}: {err}") from err
    return p


def read_plan(path: Path | str) -> Plan:
    """Read, verify and type a plan file.

    Raises:
        PlanCacheError: missing, unreadable, not JSON, wrong format, the hash does not
            match (damaged), or the body is not a plan (foreign) — the message says which
            and names the file.
    """
    body = read_document(path)
    try:
        return Plan.from_json(body)
    except PlanCacheError as err:
        raise PlanCacheError(f"plan file {str(path)!r}: {err}") from None


def read_document(path: Path | str) -> dict[str, Any]:
    """Read and verify the hashed envelope of a plan file (or a job record); its body, untyped.

    Raises:
        PlanCacheError: missing, unreadable, not JSON, wrong format, or the hash does not
            match (damaged) — the message says which.
    """
    p = Path(path)
    try:
        st = p.stat()  # follows symlinks: a loop or a dangling link fails here
        if not stat.S_ISREG(st.st_mode):  # a FIFO would block the reader forever
            raise PlanCacheError(f"plan file {str(p)!r} is not a regular file")
        if st.st_size > MAX_PLAN_BYTES:
            raise PlanCacheError(f"plan file {str(p)!r} has {st.st_size} bytes; a plan has at most {MAX_PLAN_BYTES}")
        raw = p.read_bytes()
    except OSError as err:
        raise PlanCacheError(f"plan file {str(p)!r} cannot be read: {err}") from err
    try:
        doc = json.loads(raw)
        ours = isinstance(doc, dict) and doc.get("format") == FORMAT and isinstance(doc.get("plan"), dict)
        digest = hashlib.sha256(_canonical(doc["plan"])).hexdigest() if ours else ""
    except (ValueError, RecursionError) as err:  # not JSON / not UTF-8 / absurd numbers / nested too deep
        raise PlanCacheError(f"plan file {str(p)!r} is damaged: not JSON ({type(err).__name__}: {err})") from err
    if not ours:
        raise PlanCacheError(f"plan file {str(p)!r} is not a {FORMAT} file")
    if digest != doc.get("sha256"):
        raise PlanCacheError(f"plan file {str(p)!r} is damaged: sha256 {digest} != recorded {doc.get('sha256')}")
    return doc["plan"]


def check_plan(plan: Plan, bin_type: str, surface: str) -> None:
    """Check that a (well-formed) plan is one of this bin type and surface.

    The hash only proves the file is as written and :meth:`Plan.from_json` that it is a plan;
    a file copied into the wrong folder can be both and still foreign.

    Raises:
        PlanCacheError: it is a plan for another bin type or surface.
    """
    if (plan.bin_type, plan.surface) != (bin_type, surface):
        raise PlanCacheError(
            f"plan {plan.plan_id!r:.40} is foreign: it is a plan for bin type {plan.bin_type!r:.60}, "
            f"surface {plan.surface!r:.20}; expected {bin_type!r}, {surface!r}"
        )


def list_plans(plans_dir: Path | str, bin_type: str, surface: str) -> tuple[list[Plan], list[str]]:
    """All intact plans of a bin type and surface, newest first, and why others were skipped.

    A damaged or foreign file is skipped (logged as a warning, its path and problem in the list),
    never raised: a bad cache file costs a replan, not the cycle.
    """
    folder = Path(plans_dir) / _safe(bin_type) / _safe(surface)
    plans: list[Plan] = []
    skipped: list[str] = []
    if not folder.is_dir():
        return plans, skipped
    for f in sorted(folder.glob("*.json")):
        try:
            plan = read_plan(f)
            try:
                check_plan(plan, bin_type, surface)
            except PlanCacheError as err:
                raise PlanCacheError(f"plan file {str(f)!r}: {err}") from None
            plans.append(plan)
        except PlanCacheError as err:
            log.warning("plan cache: skipping %s", err)
            skipped.append(str(err))
    plans.sort(key=lambda pl: pl.created, reverse=True)
    return plans, skipped
