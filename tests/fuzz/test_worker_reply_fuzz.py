"""Malformed worker replies: the cycle fails with a reason naming the op and the problem, never an
internal error; the daemon survives, and once the workers behave a Clear/Reset/Start cycle completes.

The workers are raw Zenoh queryables (no cellctl worker runtime), so a reply can be anything:
garbage, another message, another version, missing fields, NaN, wrong lengths, megabytes, a
non-image, a garbage error, two replies, a reply on another key. Seeded.
"""

from __future__ import annotations

import json
import logging
import random
import re
import time
from collections.abc import Callable
from typing import Any

import pytest

from cellctl.app import build_cell
from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.session import open_session
from cellctl.geometry.catalog import load_catalog
from cellctl.messages import (
    Ack,
    ApproachReply,
    CaptureReply,
    ClassifyReply,
    Command,
    CycleResult,
    MoveReply,
    PlanJobReply,
    PlanLookupReply,
    PlannedViewpoint,
    Status,
    StopRequest,
    WireMessage,
)
from tests.fakes.workers import CAM_POSE, INTRINSICS, _png, fake_identify

SEED = 8

Handler = Callable[[Any], None]

GOOD: dict[str, WireMessage] = {
    "approach": ApproachReply(joints=[0.0] * 6, flange_pose=CAM_POSE, camera_pose=CAM_POSE),
    "move": MoveReply(joints=[0.1] * 6, camera_pose=CAM_POSE),
    "capture": CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE),
    "classify": ClassifyReply(label="clean", p_dirty=0.1, model_id="raw"),
    "lookup": PlanLookupReply(
        hit=True,
        plan_id="plan-1",
        viewpoints=[PlannedViewpoint(index=i, camera_pose=CAM_POSE, joints=[0.1 * i] * 6, faces=[i]) for i in range(2)],
        coverage=0.9,
        mesh_faces=10,
    ),
    "jobs": PlanJobReply(job_id="job-1", state="queued"),
}
MISS = PlanLookupReply(hit=False, reason="no plan (test)")
KEYS = {
    "approach": lambda c: keys.robot_op(c, "approach"),
    "move": lambda c: keys.robot_op(c, "move"),
    "stop": lambda c: keys.robot_op(c, "stop"),
    "capture": keys.camera_capture,
    "classify": keys.classifier_classify,
    "lookup": lambda c: keys.worker_op(c, "planner", "lookup"),
    "jobs": keys.planner_jobs,
}


def _reply(q: Any, msg: WireMessage | bytes, op: str) -> None:
    """Reply as the worker would: capture carries the message as attachment and the image as payload."""
    body = msg if isinstance(msg, bytes) else encode(msg)
    if op == "capture":
        q.reply(q.key_expr, _png(), attachment=body)
    else:
        q.reply(q.key_expr, body)


class RawWorkers:
    """All four roles as raw queryables with liveliness; ``bad[op] = (skip, handler)`` replaces an op's
    reply from its ``skip``-th call on."""

    def __init__(self, cfg) -> None:
        c = cfg.cell_id
        self.session = open_session(cfg, "client")
        self.bad: dict[str, tuple[int, Handler]] = {}
        self.calls: dict[str, int] = {}
        self.miss = False
        self._decls = [self.session.liveliness().declare_token(keys.alive(c, r)) for r in keys.ROLES]
        for op, key in KEYS.items():
            self._decls.append(
                self.session.declare_queryable(key(c), lambda q, op=op: self._serve(op, q), complete=True)
            )
        time.sleep(0.3)  # liveliness reaches the router

    def _serve(self, op: str, q: Any) -> None:
        n = self.calls.get(op, 0)
        self.calls[op] = n + 1
        try:
            skip, handler = self.bad.get(op, (10**9, None))
            if handler is not None and n >= skip:
                handler(q)
            elif op == "stop":
                q.reply(q.key_expr, q.payload.to_bytes())
            else:
                _reply(q, MISS if op == "lookup" and self.miss else GOOD[op], op)
        except Exception as err:  # e.g. zenoh refusing a reply on another key: no reply then
            logging.getLogger(__name__).info("raw %s reply failed: %s", op, err)
        finally:
            q.drop()

    def close(self) -> None:
        for d in reversed(self._decls):
            d.undeclare()
        self.session.close()


# --- mutations of a good reply --------------------------------------------------------------


def _paths(obj: Any, keep: Callable[[tuple, Any], bool], at: tuple = ()) -> list[tuple]:
    out = [at] if at and keep(at, obj) else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, keep, (*at, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, keep, (*at, i))
    return out


def _set(obj: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        obj = obj[k]
    obj[path[-1]] = value


BAD_VALUES: dict[str, list[tuple[tuple, Any]]] = {
    "approach": [(("flange_pose", "orientation"), [0, 0, 0, 0]), (("joints",), ["a"] * 6)],
    "move": [(("camera_pose", "frame_id"), "x" * 1000), (("joints",), [None] * 6)],
    "capture": [(("intrinsics", "fx"), -1.0), (("intrinsics", "width"), 0), (("format",), "gif")],
    "classify": [(("p_dirty",), 1.5), (("label",), "grimy"), (("model_id",), "m" * 5000)],
    "lookup": [(("viewpoints",), []), (("viewpoints", 0, "index"), -1), (("coverage",), 7.0)],
    "jobs": [(("state",), "exploded"), (("job_id",), "j" * 1000)],
}

# what the reason must say, per mutation kind (besides the op's name)
PROBLEM = {
    "garbage": r"not valid JSON|unusable reply",
    "wrong_type": r"answered \w+ with cellctl/",
    "wrong_version": r"version 2 is not supported",
    "missing_field": r"Field required",
    "nan_inf": r"finite",
    "wrong_length": r"at least|at most|tuple|Field required|Tuple should have",
    "bad_values": r"unusable reply|no viewpoints|not a rotation",
    "huge": r"exceeds the limit",
    "not_image": r"not a png image",
    "error_garbage": r"failed \w+:",
    "two_replies": r"2 replies",
    "other_key": r"0 replies",
}
KINDS = tuple(PROBLEM)


def mutation(op: str, kind: str, rng: random.Random) -> Handler | None:
    """A handler replying ``kind`` of broken for ``op``, or None when ``kind`` does not apply."""
    good = json.loads(encode(GOOD[op]))
    if kind == "garbage":
        data = rng.randbytes(rng.choice([1, 7, 300]))
        return lambda q: _reply(q, data, op)
    if kind == "wrong_type":
        other = rng.choice(
            [StopRequest(reason="x"), Status(cell="c", state="Idle", state_code=4, available_commands=[])]
        )
        return lambda q: _reply(q, other, op)
    if kind == "wrong_version":
        return lambda q: _reply(q, json.dumps({**good, "v": 2}).encode(), op)
    if kind == "missing_field":
        model = type(GOOD[op])
        required = [n for n, f in model.model_fields.items() if f.is_required()]
        drop = rng.choice(required)
        return lambda q: _reply(q, json.dumps({k: v for k, v in good.items() if k != drop}).encode(), op)
    if kind == "nan_inf":
        floats = _paths(good, lambda p, v: isinstance(v, float) and p[0] != "p_dirty" or p == ("p_dirty",))
        if not floats:
            return None
        obj = json.loads(json.dumps(good))
        _set(obj, rng.choice(floats), rng.choice([float("nan"), float("inf"), float("-inf")]))
        return lambda q: _reply(q, json.dumps(obj).encode(), op)
    if kind == "wrong_length":
        lists = _paths(good, lambda p, v: isinstance(v, list) and p[-1] in ("joints", "position", "orientation"))
        if not lists:
            return None
        obj = json.loads(json.dumps(good))
        path = rng.choice(lists)
        value = obj
        for k in path:
            value = value[k]
        _set(obj, path, rng.choice([value[:-1], [*value, 0.0], []]))
        return lambda q: _reply(q, json.dumps(obj).encode(), op)
    if kind == "bad_values":
        path, value = rng.choice(BAD_VALUES[op])
        obj = json.loads(json.dumps(good))
        _set(obj, path, value)
        return lambda q: _reply(q, json.dumps(obj).encode(), op)
    if kind == "huge":
        blob = json.dumps({**good, "pad": "z" * (5 * 1024 * 1024)}).encode()
        return lambda q: _reply(q, blob, op)
    if kind == "not_image":
        if op != "capture":
            return None
        data = rng.choice([b"", b"GIF89a" + rng.randbytes(100), rng.randbytes(2000)])
        return lambda q: q.reply(q.key_expr, data, attachment=encode(GOOD["capture"]))
    if kind == "error_garbage":
        data = rng.choice([rng.randbytes(50), b"\xff\xfe\x00", b"{" * 10_000, b"e" * 300_000, b""])
        return lambda q: q.reply_err(data)
    if kind == "two_replies":
        return lambda q: (_reply(q, GOOD[op], op), _reply(q, GOOD[op], op))
    if kind == "other_key":
        other = keys.status("elsewhere")
        return lambda q: q.reply(other, encode(GOOD[op]))
    raise AssertionError(kind)


# --- the cell and a PLC ---------------------------------------------------------------------


class Harness:
    def __init__(self, cfg) -> None:
        self.cfg = cfg
        self.cell = build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
        self.sup = self.cell.supervisor
        self.workers = RawWorkers(cfg)
        self.plc = open_session(cfg, "client")

    def cmd(self, name: str) -> Ack:
        (r,) = list(self.plc.get(keys.cmd(self.cfg.cell_id), payload=encode(Command(command=name)), timeout=5))
        ack = decode_as(Ack, r.ok.payload.to_bytes())
        assert ack.accepted, ack.reason
        return ack

    def wait(self, *states: str, timeout: float = 20.0) -> str:
        deadline = time.monotonic() + timeout
        while self.sup.top_state not in states:
            assert time.monotonic() < deadline, f"still in {self.sup.state}, waited for {states}"
            time.sleep(0.005)
        return self.sup.top_state

    def status(self) -> Status:
        (r,) = list(self.plc.get(keys.status(self.cfg.cell_id), timeout=5))
        return decode_as(Status, r.ok.payload.to_bytes())

    def cycle(self) -> CycleResult:
        """Reset → Start → the end of the cycle; Clear afterwards when it aborted. Returns its result."""
        last = self.sup.results[-1].cycle_id if self.sup.results else None  # the list keeps the last 50
        self.cmd("reset")
        self.wait("Idle")
        self.cmd("start")
        end = self.wait("Aborted", "Complete")
        deadline = time.monotonic() + 5
        while not self.sup.results or self.sup.results[-1].cycle_id == last:
            assert time.monotonic() < deadline, "no CycleResult"
            time.sleep(0.005)
        if end == "Aborted":
            self.cmd("clear")
            self.wait("Stopped")
        else:
            self.cmd("stop")
            self.wait("Stopped")
        return self.sup.results[-1]

    def close(self) -> None:
        self.plc.close()
        self.workers.close()
        self.cell.close()


@pytest.fixture
def harness(cfg, caplog):
    caplog.set_level(logging.WARNING, logger="cellctl")
    cfg.supervisor.timeouts.default = 2.0
    h = Harness(cfg)
    yield h
    h.close()
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR and r.name.startswith("cellctl")]
    assert not errors, errors  # a step or the dispatcher crashed


# (op, skip): which call of the op is broken; capture 1 = the first scanning capture
TARGETS = [("approach", 0), ("capture", 0), ("lookup", 0), ("move", 0), ("capture", 1), ("classify", 0), ("jobs", 0)]


def _run_case(h: Harness, op: str, skip: int, kind: str, handler: Handler) -> str:
    h.workers.calls.clear()
    h.workers.miss = op == "jobs"
    h.workers.bad = {op: (skip, handler)}
    res = h.cycle()
    assert res.outcome in ("failed", "aborted"), (op, kind, res.outcome, res.reason)
    reason = res.reason or ""
    assert "internal error" not in reason, reason
    assert op in reason, (op, kind, reason)
    assert re.search(PROBLEM[kind], reason), (op, kind, reason)
    return reason


def _recovered(h: Harness) -> None:
    h.workers.bad = {}
    h.workers.miss = False
    res = h.cycle()
    assert res.outcome == "completed" and res.verdict == "clean", res.reason
    assert h.status().state == "Stopped"


def test_every_kind_of_broken_reply_on_every_op_fails_the_cycle_cleanly(harness) -> None:
    rng = random.Random(SEED)
    ran = 0
    for op, skip in TARGETS:
        for kind in KINDS:
            handler = mutation(op, kind, rng)
            if handler is None:
                continue
            _run_case(harness, op, skip, kind, handler)
            ran += 1
    assert ran >= 70
    _recovered(harness)


def test_a_broken_stop_reply_still_reaches_aborted(harness) -> None:
    rng = random.Random(SEED)
    harness.workers.bad["approach"] = (0, lambda q: q.reply_err(b"base cannot park"))
    for kind in ("garbage", "wrong_version", "error_garbage", "two_replies", "other_key", "huge"):
        harness.workers.bad["stop"] = (0, mutation("approach", kind, rng))  # any bytes will do for a stop
        res = harness.cycle()
        assert res.outcome == "failed" and "base cannot park" in res.reason
    assert harness.workers.calls["stop"] >= 6
    harness.workers.bad.clear()
    _recovered(harness)


@pytest.mark.slow
def test_three_hundred_random_broken_replies(harness) -> None:
    rng = random.Random(SEED + 1)
    ran = 0
    while ran < 300:
        op, skip = rng.choice(TARGETS)
        kind = rng.choice(KINDS)
        handler = mutation(op, kind, rng)
        if handler is None:
            continue
        _run_case(harness, op, skip, kind, handler)
        ran += 1
        if ran % 50 == 0:
            _recovered(harness)
    _recovered(harness)
