"""Every Zenoh key expression cellctl uses, built by functions (wire contract v1).

Nothing else in the code spells a key. Layout: ``cell/<cell_id>/...``.
"""

from __future__ import annotations

import re

from cellctl.errors import ConfigError

__all__ = [
    "ROLES",
    "alive",
    "alive_all",
    "alive_instances",
    "camera_capture",
    "check_cell_id",
    "classifier_classify",
    "cmd",
    "cmd_ack",
    "command_keys",
    "events",
    "cell_from_key",
    "planner_job_progress",
    "planner_jobs",
    "planner_jobs_any",
    "planner_lookup_any",
    "planner_wash_plan_any",
    "pool_alive",
    "pool_claim",
    "pool_done",
    "pool_stats",
    "prefix",
    "replay_all",
    "replay_prefix",
    "result",
    "role_from_alive_key",
    "robot_joints",
    "robot_op",
    "sim_state",
    "status",
    "worker_all",
    "worker_fault",
    "worker_op",
]

ROLES = ("robot", "camera", "classifier", "planner")
"""Worker roles; the supervisor's own liveliness role is ``supervisor``."""

_CELL_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9-]{0,63}$")
_OP = re.compile(r"^[a-z][a-z0-9_-]{0,63}$")


def check_cell_id(cell_id: str) -> str:
    """Return ``cell_id`` if it is a valid single key chunk, else raise ConfigError."""
    if not isinstance(cell_id, str) or not _CELL_ID.match(cell_id):
        raise ConfigError(
            f"cell id {cell_id!r} is invalid: expected 1-64 letters, digits or '-', starting with a letter or digit"
        )
    return cell_id


def prefix(cell_id: str) -> str:
    return f"cell/{check_cell_id(cell_id)}"


def cmd(cell_id: str) -> str:
    """PackML commands: subscriber and queryable on the supervisor."""
    return f"{prefix(cell_id)}/cmd"


def cmd_ack(cell_id: str) -> str:
    return f"{prefix(cell_id)}/cmd/ack"


def command_keys(cell_id: str) -> tuple[str, str]:
    """The command exchange of a cell (``cmd`` and ``cmd/ack``): what a replay onto live keys never publishes."""
    return cmd(cell_id), cmd_ack(cell_id)


def status(cell_id: str) -> str:
    return f"{prefix(cell_id)}/status"


def result(cell_id: str) -> str:
    return f"{prefix(cell_id)}/result"


def events(cell_id: str) -> str:
    return f"{prefix(cell_id)}/events"


def worker_op(cell_id: str, role: str, op: str) -> str:
    """Queryable key of one operation of a worker role, e.g. ``cell/cell1/robot/move``."""
    if role not in ROLES:
        raise ConfigError(f"worker role {role!r} is unknown; expected one of {list(ROLES)}")
    if not _OP.match(op):
        raise ConfigError(f"worker op {op!r} is invalid: expected lower-case letters, digits, '_' or '-'")
    return f"{prefix(cell_id)}/{role}/{op}"


def worker_all(cell_id: str, role: str) -> str:
    """Every key under one worker role (its ops and publications): ``cell/<id>/<role>/**``."""
    if role not in ROLES:
        raise ConfigError(f"worker role {role!r} is unknown; expected one of {list(ROLES)}")
    return f"{prefix(cell_id)}/{role}/**"


def worker_fault(cell_id: str, role: str) -> str:
    """Where a worker reports a fault (an error ``Event``) just before it withdraws its token:
    ``cell/<id>/<role>/fault`` — under its own role's keys, which its principal may publish on (and one
    subscription per role, not ``*/fault``: the ACL matches a subscriber's key against the role's keys)."""
    if role not in ROLES:
        raise ConfigError(f"worker role {role!r} is unknown; expected one of {list(ROLES)}")
    return f"{prefix(cell_id)}/{role}/fault"


def robot_op(cell_id: str, op: str) -> str:
    return worker_op(cell_id, "robot", op)


def robot_joints(cell_id: str) -> str:
    return f"{prefix(cell_id)}/robot/joints"


def camera_capture(cell_id: str) -> str:
    return worker_op(cell_id, "camera", "capture")


def sim_state(cell_id: str) -> str:
    """Sim only: the twin's scenario + joints; queryable and publisher on the sim robot worker."""
    return f"{prefix(cell_id)}/sim/state"


def classifier_classify(cell_id: str) -> str:
    return worker_op(cell_id, "classifier", "classify")


def planner_jobs(cell_id: str) -> str:
    return f"{prefix(cell_id)}/planner/jobs"


def planner_job_progress(cell_id: str, job_id: str = "*") -> str:
    return f"{prefix(cell_id)}/planner/jobs/{job_id}/progress"


def planner_jobs_any() -> str:
    """The jobs key of every cell: the planner pool's queue serves them all (``cell/*/planner/jobs``)."""
    return "cell/*/planner/jobs"


def planner_lookup_any() -> str:
    """The plan-cache lookup of every cell: pool workers answer for all cells (one shared cache)."""
    return "cell/*/planner/lookup"


def planner_wash_plan_any() -> str:
    """Wash planning for every cell: pool workers plan any cell's wash (``cell/*/planner/wash_plan``)."""
    return "cell/*/planner/wash_plan"


def cell_from_key(key: str) -> str:
    """The cell id of a ``cell/<id>/...`` key, else ConfigError."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != "cell":
        raise ConfigError(f"key {key!r} is not a cell key; expected 'cell/<id>/...'")
    return check_cell_id(parts[1])


_REPLAY = "replay"
"""Where ``cellctl replay`` republishes a recorded cycle: outside every cell's keys, so no supervisor,
worker or PLC of a live cell hears it (issue 32: a replay drove a live cell)."""
_CHUNK_UNSAFE = re.compile(r"[^A-Za-z0-9._-]")


def replay_prefix(name: str) -> str:
    """The key prefix of one replayed log, ``replay/<name>/`` (``name``: its cycle id or file stem; any
    character that may not stand in a key chunk becomes ``_``). A recorded key ``cell/cell1/status`` is
    republished as ``replay/<name>/cell/cell1/status``."""
    chunk = _CHUNK_UNSAFE.sub("_", str(name))[:64] or "_"
    return f"{_REPLAY}/{chunk}/"


def replay_all() -> str:
    """Every replayed key, ``replay/**`` (the replay principal's only grant to publish)."""
    return f"{_REPLAY}/**"


_POOL = "pool/planner"
"""The planner pool's own keys (compute host): not under any cell, the pool serves several."""


def pool_claim() -> str:
    """Queryable of the pool's job queue: a worker's claim gets the next job (or none)."""
    return f"{_POOL}/claim"


def pool_done() -> str:
    """Queryable of the pool's job queue: a worker reports a claimed job done or failed."""
    return f"{_POOL}/done"


def pool_stats() -> str:
    """Queryable of the pool's job queue: counters (jobs per worker, requeued, planned twice)."""
    return f"{_POOL}/stats"


def pool_alive(instance: str | None = None) -> str:
    """Liveliness of a pool worker; a claim is held exactly as long as its claimant's token lives."""
    if instance is None:
        return f"{_POOL}/alive/*"
    if not _OP.match(instance):
        raise ConfigError(f"instance name {instance!r} is invalid: expected lower-case letters, digits, '_' or '-'")
    return f"{_POOL}/alive/{instance}"


def alive(cell_id: str, role: str, instance: str | None = None) -> str:
    """Liveliness token of one live worker (or ``supervisor``).

    Roles that may run several instances (planners) append an instance chunk so that one
    instance leaving does not hide the others: ``cell/<id>/alive/planner/<instance>``.
    """
    if role not in ROLES and role != "supervisor":
        raise ConfigError(f"liveliness role {role!r} is unknown; expected one of {[*ROLES, 'supervisor']}")
    key = f"{prefix(cell_id)}/alive/{role}"
    if instance is not None:
        if not _OP.match(instance):
            raise ConfigError(f"instance name {instance!r} is invalid: expected lower-case letters, digits, '_' or '-'")
        key += f"/{instance}"
    return key


def alive_instances(cell_id: str, role: str) -> str:
    """The liveliness tokens of every named instance of ``role``: ``cell/<id>/alive/<role>/*``."""
    return f"{alive(cell_id, role)}/*"


def alive_all(cell_id: str) -> str:
    return f"{prefix(cell_id)}/alive/**"


def role_from_alive_key(cell_id: str, key: str) -> str | None:
    """The role named by a liveliness key of this cell, or None if the key is not one."""
    head = f"{prefix(cell_id)}/alive/"
    if not key.startswith(head):
        return None
    role = key[len(head) :].split("/", 1)[0]
    return role if role in ROLES or role == "supervisor" else None
