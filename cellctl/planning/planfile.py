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
import logging
import math
import os
import stat
import tempfile
from pathlib import Path
from typing import Any

from cellctl.errors import PlanCacheError

__all__ = ["FORMAT", "MAX_PLAN_BYTES", "check_plan", "list_plans", "plan_path", "read_plan", "write_plan"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

FORMAT = "cellctl-plan/1"

MAX_PLAN_BYTES = 32 * 1024 * 1024
"""Largest plan file read (a fast-mode plan is ~100 kB); anything bigger is not one of ours."""


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


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _vector(v: Any, n: int) -> bool:
    return isinstance(v, list) and len(v) == n and all(_number(x) for x in v)


def _matrix4(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 4 and all(_vector(row, 4) for row in v)


def _viewpoints(vps: Any, what: str) -> str | None:
    if not isinstance(vps, list):
        return f"{what} is {type(vps).__name__}, expected a list"
    for k, vp in enumerate(vps):
        if not isinstance(vp, dict):
            return f"{what}[{k}] is {type(vp).__name__}, expected an object"
        if not _matrix4(vp.get("T_bin_cam")):
            return f"{what}[{k}].T_bin_cam is not a 4x4 matrix of finite numbers"
        if not _vector(vp.get("q"), 6):
            return f"{what}[{k}].q is not 6 finite joint angles"
        faces = vp.get("faces")
        if not isinstance(faces, list) or not all(isinstance(f, int) and not isinstance(f, bool) for f in faces):
            return f"{what}[{k}].faces is not a list of face ids"
    return None


def check_plan(plan: dict[str, Any], bin_type: str, surface: str) -> None:
    """Check that an intact plan file holds a plan of this bin type and surface in the shape lookups use.

    The hash only proves the file is as written; a file written by another tool or version, or
    copied into the wrong folder, can be intact and still foreign.

    Raises:
        PlanCacheError: the first problem found.
    """
    problem = None
    for key in ("plan_id", "mesh_sha256", "robot_model_id"):
        if not isinstance(plan.get(key), str) or not plan[key]:
            problem = f"{key} is {plan.get(key)!r:.60}, expected a non-empty string"
            break
    if problem is None and (plan.get("bin_type"), plan.get("surface")) != (bin_type, surface):
        problem = (
            f"it is a plan for bin type {plan.get('bin_type')!r:.60}, surface {plan.get('surface')!r:.20}; "
            f"expected {bin_type!r}, {surface!r}"
        )
    if problem is None and not _matrix4(plan.get("T_base_bin")):
        problem = "T_base_bin is not a 4x4 matrix of finite numbers"
    if problem is None and not isinstance(plan.get("params", {}), dict):
        problem = "params is not an object"
    if problem is None and "q_start" in plan and not _vector(plan["q_start"], 6):
        problem = "q_start is not 6 finite joint angles"
    if problem is None and not _number(plan.get("coverage", 0.0)):
        problem = f"coverage is {plan.get('coverage')!r:.30}, expected a number"
    problem = problem or _viewpoints(plan.get("viewpoints", []), "viewpoints")
    problem = problem or _viewpoints(plan.get("reachable", []), "reachable")
    if problem is not None:
        raise PlanCacheError(f"plan {plan.get('plan_id')!r:.40} is foreign: {problem}")


def list_plans(plans_dir: Path | str, bin_type: str, surface: str) -> tuple[list[dict[str, Any]], list[str]]:
    """All intact plans of a bin type and surface, newest first, and why others were skipped.

    A damaged or foreign file is skipped (logged as a warning, its path and problem in the list),
    never raised: a bad cache file costs a replan, not the cycle.
    """
    folder = Path(plans_dir) / _safe(bin_type) / _safe(surface)
    plans, skipped = [], []
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
    plans.sort(key=lambda pl: str(pl.get("created", "")), reverse=True)
    return plans, skipped
