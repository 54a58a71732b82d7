"""Plan files and the plan cache in ``models/plans/`` (ARCHITECTURE §6).

A plan file is JSON: ``{"format": "cellctl-plan/1", "sha256": <hex of the canonical body>,
"plan": {...}}``. Writes go to a temporary file in the same folder, are fsynced and renamed
over the target, so a reader (or a crash) never sees half a plan. A file whose hash does not
match, that is not JSON, or has the wrong format is *damaged*: lookups skip it (cache miss
with the reason), they never crash. Light module: json/hashlib only, the supervisor may import it.

Layout: ``<plans_dir>/<bin_type>/<surface>/<plan_id>.json``; the newest plan whose base pose
is closest to the measured one wins.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from cellctl.errors import PlanCacheError

__all__ = ["FORMAT", "list_plans", "plan_path", "read_plan", "write_plan"]

FORMAT = "cellctl-plan/1"


def _canonical(plan: dict[str, Any]) -> bytes:
    return json.dumps(plan, sort_keys=True, separators=(",", ":")).encode()


def plan_path(plans_dir: Path | str, plan: dict[str, Any]) -> Path:
    """Where ``plan`` lives in the cache."""
    return Path(plans_dir) / _safe(plan["bin_type"]) / _safe(plan["surface"]) / f"{_safe(plan['plan_id'])}.json"


def _safe(name: str) -> str:
    s = "".join(c if c.isalnum() or c in "-_." else "_" for c in str(name))
    if not s or s.startswith("."):
        raise PlanCacheError(f"name {name!r} cannot be used in a plan path; expected letters, digits, '-', '_'")
    return s


def write_plan(plan: dict[str, Any], path: Path | str) -> Path:
    """Atomically write ``plan`` to ``path`` (temp file + fsync + rename).

    Raises:
        PlanCacheError: the folder cannot be created or the file written.
    """
    p = Path(path)
    body = _canonical(plan)
    doc = {"format": FORMAT, "sha256": hashlib.sha256(body).hexdigest(), "plan": plan}
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


def read_plan(path: Path | str) -> dict[str, Any]:
    """Read and verify a plan file.

    Raises:
        PlanCacheError: missing, unreadable, not JSON, wrong format, or the hash does not
            match (damaged) — the message says which.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as err:
        raise PlanCacheError(f"plan file {str(p)!r} cannot be read: {err}") from err
    try:
        doc = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise PlanCacheError(f"plan file {str(p)!r} is damaged: not JSON ({err})") from err
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("plan"), dict):
        raise PlanCacheError(f"plan file {str(p)!r} is not a {FORMAT} file")
    digest = hashlib.sha256(_canonical(doc["plan"])).hexdigest()
    if digest != doc.get("sha256"):
        raise PlanCacheError(f"plan file {str(p)!r} is damaged: sha256 {digest} != recorded {doc.get('sha256')}")
    return doc["plan"]


def list_plans(plans_dir: Path | str, bin_type: str, surface: str) -> tuple[list[dict[str, Any]], list[str]]:
    """All intact plans of a bin type and surface, newest first, and why others were skipped."""
    folder = Path(plans_dir) / _safe(bin_type) / _safe(surface)
    plans, skipped = [], []
    if not folder.is_dir():
        return plans, skipped
    for f in sorted(folder.glob("*.json")):
        try:
            plans.append(read_plan(f))
        except PlanCacheError as err:
            skipped.append(str(err))
    plans.sort(key=lambda pl: str(pl.get("created", "")), reverse=True)
    return plans, skipped
