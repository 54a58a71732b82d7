"""Seeded hostile-payload fuzzing of the PLC command key (``cellctl bench fuzz``, ``tests/fuzz``).

:class:`CommandFuzzer` makes payloads from one ``random.Random(seed)``: random bytes, broken
UTF-8, truncated JSON, recursion bombs, oversize payloads, wrong types for every field, unknown
fields, wrong message type or version, bad ``cntrl_cmd`` codes, NaN/Infinity, hostile Start
params, repeated keys, BOMs and UTF-16, and valid commands (which move the machine) mixed in.

:class:`FuzzTarget` sends each case to a running cell, by query or by put, and checks the
command contract on every one:

* exactly one Ack comes back (the query's single reply, or one Ack on ``cmd/ack`` for a put,
  matched by order and ``request_id``);
* a rejected command changes nothing (same full state, Ack names the state it was in);
* a payload that must be refused is refused; a valid command is accepted exactly when the
  PackML table allows it in the state it arrived in;
* the dispatcher stays alive (a status query answers) and logs no error.

The cell runs with one real worker, the sim robot, slowed down (:data:`FUZZ_OVERRIDES`: the
base takes an hour to park) and the only required role, so a started cycle waits in
``Execute.approaching`` with a real request in flight for as long as the fuzzer likes;
Hold/Suspend/Complete/Stop/Abort/Clear then take the machine through every waiting state of
PackML, each with the robot's real ``stop``.
"""

from __future__ import annotations

import argparse
import json
import logging
import queue
import random
import shutil
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.errors import CellError
from cellctl.messages import MESSAGE_TYPES, Ack, Command, PackMLCommand

__all__ = [
    "CATEGORIES",
    "FUZZ_OVERRIDES",
    "CommandFuzzer",
    "FuzzCase",
    "FuzzTarget",
    "bench_fuzz",
    "run_fuzz",
    "slow_sim_robot",
]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

NAMES = [c.name for c in PackMLCommand]
REJECT = "reject"
"""``FuzzCase.expect`` for a payload every state must refuse."""

STABLE = frozenset({"Stopped", "Idle", "Held", "Suspended", "Complete", "Aborted", "Execute.approaching"})
"""States the machine stays in without a command (Execute: the slowed robot never finishes parking)."""

FUZZ_OVERRIDES = [
    "supervisor.required_workers=[robot]",
    "robot.speed_scale=0.001",  # parking takes 4000 s: a started cycle rests in Execute.approaching
    "supervisor.timeouts.approach=3600",
    "supervisor.auto_reset=false",
]
"""Config the fuzzed cell runs with (see :func:`slow_sim_robot`)."""

_CMD = "cellctl/Command"
_FIELDS = ("type", "v", "command", "cntrl_cmd", "request_id", "params")


@dataclass(frozen=True)
class FuzzCase:
    """One payload for the command key.

    Attributes:
        category: which generator made it (see :data:`CATEGORIES`).
        payload: the bytes sent.
        expect: :data:`REJECT`, a PackML command name (a valid command: accepted exactly when
            allowed in the current state), or None (either answer is fine).
        request_id: the ``request_id`` a decoded Ack must carry back (valid commands only).
    """

    category: str
    payload: bytes
    expect: str | None = REJECT
    request_id: str | None = None


def _dump(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode()


class CommandFuzzer:
    """Hostile command payloads from one seeded ``random.Random`` (no hypothesis needed).

    Args:
        seed: the seed; the same seed gives the same cases.
        max_bytes: the daemon's ``supervisor.max_command_bytes`` (oversize cases straddle it).
    """

    def __init__(self, seed: int, max_bytes: int = 64 * 1024) -> None:
        self.seed = seed
        self.rng = random.Random(seed)
        self.max_bytes = max_bytes
        self._n = 0
        self._gens: dict[str, Callable[[], FuzzCase]] = {
            name[len("_c_") :]: getattr(self, name) for name in sorted(dir(self)) if name.startswith("_c_")
        }

    # --- building blocks ------------------------------------------------------------------

    def _text(self, n: int | None = None) -> str:
        """Random text with control characters, non-BMP, bidi overrides and lone surrogates."""
        r = self.rng
        n = r.choice([0, 1, 5, 20, 127, 128, 129, 1000]) if n is None else n
        pools = ["abcXYZ019 -_/.", '\x00\x01\x1b\x7f\n\t"\\', "éß中文😀\u202e\ufeff", "\ud800\udfff"]
        weights = [8, 2, 2, 1]
        return "".join(r.choice(r.choices(pools, weights)[0]) for _ in range(n))

    def _value(self, depth: int = 0) -> Any:
        """Any JSON-able value (NaN and Infinity included, as Python's json writes them)."""
        r = self.rng
        kind = r.choice(["null", "bool", "int", "bigint", "float", "special", "str", "list", "dict"])
        if kind == "null":
            return None
        if kind == "bool":
            return r.random() < 0.5
        if kind == "int":
            return r.randint(-20, 20)
        if kind == "bigint":
            return r.choice([2**31, 2**63, -(2**63) - 1, 10**30, -(10**100)])
        if kind == "float":
            return r.choice([0.5, -1.5, 1e-300, 1e300, 2.0])
        if kind == "special":
            return r.choice([float("nan"), float("inf"), float("-inf")])
        if kind == "str":
            return self._text()
        if depth > 2:
            return []
        if kind == "list":
            return [self._value(depth + 1) for _ in range(r.randint(0, 4))]
        return {self._text(r.randint(0, 8)): self._value(depth + 1) for _ in range(r.randint(0, 4))}

    def _rid(self) -> str:
        self._n += 1
        return f"fz-{self.seed}-{self._n}"

    def _valid(self, name: str | None = None, rid: bool = True, start_params: bool = True) -> dict[str, Any]:
        """A valid Command object (``name`` or a random one, by name or by code)."""
        r = self.rng
        name = name or r.choice(NAMES)
        obj: dict[str, Any] = {"type": _CMD, "v": 1}
        if r.random() < 0.5:
            obj["command"] = name
        else:
            obj["cntrl_cmd"] = PackMLCommand[name].value
        if rid:
            obj["request_id"] = self._rid()
        if name == "start" and start_params and r.random() < 0.3:
            obj["params"] = r.choice(
                [
                    {"mode": "evaluate"},
                    {"surface": r.choice(["external", "internal"])},
                    {"mode": "collect", "label": r.choice(["clean", "dirty"]), "perturb_m": 0.01, "seed": 7},
                ]
            )
        if r.random() < 0.5:  # key order is no part of the contract
            items = list(obj.items())
            r.shuffle(items)
            obj = dict(items)
        return obj

    def _expect_valid(self, category: str, obj: dict[str, Any], payload: bytes | None = None) -> FuzzCase:
        name = obj.get("command") or PackMLCommand(obj["cntrl_cmd"]).name
        return FuzzCase(category, payload if payload is not None else _dump(obj), name, obj.get("request_id"))

    # --- generators: one per category -------------------------------------------------------

    def _c_empty(self) -> FuzzCase:
        return FuzzCase("empty", self.rng.choice([b"", b" ", b"\n\t\r", b"null", b"{}", b"\x00"]))

    def _c_random_bytes(self) -> FuzzCase:
        return FuzzCase("random_bytes", self.rng.randbytes(self.rng.choice([1, 2, 8, 64, 512, 4096])))

    def _c_invalid_utf8(self) -> FuzzCase:
        r = self.rng
        good = _dump(self._valid())
        bad = r.choice([b"\xff", b"\xfe\xff", b"\xc3\x28", b"\xed\xa0\x80", b"\xc0\xaf", b"\xf4\x90\x80\x80", b"\x80"])
        at = r.randrange(len(good) + 1)
        return FuzzCase("invalid_utf8", good[:at] + bad + good[at:])

    def _c_truncated_json(self) -> FuzzCase:
        good = _dump(self._valid())
        return FuzzCase("truncated_json", good[: self.rng.randrange(1, len(good))])

    def _c_nesting_bomb(self) -> FuzzCase:
        r = self.rng
        d = r.choice([33, 100, 990, 1000, 5000, 30000])
        kind = r.choice(["open_arrays", "closed_arrays", "objects", "in_params"])
        if kind == "open_arrays":
            payload = b"[" * d
        elif kind == "closed_arrays":
            payload = b"[" * d + b"]" * d
        elif kind == "objects":
            payload = b'{"a":' * d + b"1" + b"}" * d
        else:
            head = _dump({"type": _CMD, "v": 1, "command": "start"})[:-1]
            payload = head + b',"params":{"mode":' + b"[" * d + b"]" * d + b"}}"
        return FuzzCase("nesting_bomb", payload[: self.max_bytes + 16])

    def _c_oversize(self) -> FuzzCase:
        r = self.rng
        obj = self._valid(start_params=False)
        good = _dump(obj)
        if r.random() < 0.3:
            # exactly at the limit: still a command (whitespace is valid JSON)
            return self._expect_valid("oversize", obj, good + b" " * (self.max_bytes - len(good)))
        extra = r.choice([1, 100, 10_000, 1_000_000])
        if r.random() < 0.5:
            return FuzzCase("oversize", good + b" " * (self.max_bytes - len(good) + extra))
        obj["request_id"] = "x" * (self.max_bytes + extra)
        return FuzzCase("oversize", _dump(obj))

    def _c_huge_strings(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        target = r.choice(["request_id", "command", "type", "param"])
        big = "y" * r.choice([129, 4096, self.max_bytes // 2])
        if target == "param":
            obj = {"type": _CMD, "v": 1, "command": "start", "params": {"dataset": big, "mode": big}}
        else:
            obj[target] = big
        return FuzzCase("huge_strings", _dump(obj))

    def _c_hostile_request_id(self) -> FuzzCase:
        obj = self._valid(start_params=False)
        rid = self._text(self.rng.choice([1, 10, 64, 128]))
        obj["request_id"] = rid
        payload = json.dumps(obj, ensure_ascii=self.rng.random() < 0.5).encode("utf-8", "surrogatepass")
        if any("\ud800" <= c <= "\udfff" for c in rid):
            return FuzzCase("hostile_request_id", payload)  # lone surrogates are not text
        return self._expect_valid("hostile_request_id", obj, payload)

    def _c_not_an_object(self) -> FuzzCase:
        v = self._value()
        while isinstance(v, dict):
            v = self._value()
        return FuzzCase("not_an_object", json.dumps(v).encode())

    def _c_wrong_field_type(self) -> FuzzCase:
        r = self.rng
        wrong = {
            "type": [1, None, [], {}, True, "cellctl/command", " cellctl/Command"],
            "v": ["1", [], {}, None, 1.5, [1]],
            "command": [1, [], {}, True, "RESET", "reset ", "", "jump", "start\x00"],
            "cntrl_cmd": ["1", True, False, [], {}, 1.5, "reset"],
            "request_id": [1, [], {}, True, 1.5, {"id": "x"}],
            "params": [[], "x", 1, True, None, [["mode", "collect"]]],
        }
        obj = self._valid(start_params=False)
        f = r.choice(_FIELDS)
        if f == "cntrl_cmd":
            obj.pop("command", None)
        if f == "command":
            obj.pop("cntrl_cmd", None)
        obj[f] = r.choice(wrong[f])
        return FuzzCase("wrong_field_type", _dump(obj))

    def _c_unknown_fields(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        for _ in range(r.randint(1, 4)):
            k = r.choice(["Command", "cmd", "TYPE", "state", "__proto__", "constructor", "param", self._text(6)])
            if k not in _FIELDS:
                obj[k] = self._value()
        if set(obj) <= set(_FIELDS):
            obj["extra"] = 1
        return FuzzCase("unknown_fields", _dump(obj))

    def _c_wrong_type_or_version(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        if r.random() < 0.5:
            others = sorted(t for t in MESSAGE_TYPES if t != _CMD)
            obj["type"] = r.choice([*others, "cellctl/Cmd", "Command", "", "cellctl/Command/v1"])
        else:
            obj["v"] = r.choice([0, 2, -1, 2**64, "1", 1.5, None, True, [1]])
        return FuzzCase("wrong_type_or_version", _dump(obj))

    def _c_bad_cntrl_cmd(self) -> FuzzCase:
        r = self.rng
        raw = r.choice(
            [b"0", b"11", b"-1", b"2147483648", b"9223372036854775808", b"1e400", b"1.5", b"2.000001"]
            + [b"true", b"false", b'"2"', b'"reset"', b"NaN", b"Infinity", b"-Infinity", b"null", b"[2]"]
            + [b"1" * 5000, b"-" + b"9" * 4301]
        )
        rid = f',"request_id":"{self._rid()}"' if r.random() < 0.5 else ""
        return FuzzCase("bad_cntrl_cmd", b'{"type":"cellctl/Command","v":1,"cntrl_cmd":' + raw + rid.encode() + b"}")

    def _c_command_and_code(self) -> FuzzCase:
        r = self.rng
        name = r.choice(NAMES)
        obj: dict[str, Any] = {"type": _CMD, "v": 1}
        if r.random() < 0.7:  # both, even when they agree
            obj["command"] = name
            obj["cntrl_cmd"] = PackMLCommand[r.choice([name, *NAMES])].value
        else:  # neither
            obj["request_id"] = self._rid()
        return FuzzCase("command_and_code", _dump(obj))

    def _c_nan_infinity(self) -> FuzzCase:
        r = self.rng
        obj = self._valid()
        special = r.choice([float("nan"), float("inf"), float("-inf")])
        where = r.choice(["v", "cntrl_cmd", "request_id", "command", "type", "param"])
        if where == "param":
            obj.pop("command", None)
            obj.update(cntrl_cmd=2, params={r.choice(["perturb_m", "seed", "mode", "nan"]): special})
        else:
            if where == "cntrl_cmd":
                obj.pop("command", None)
            obj[where] = special
        return FuzzCase("nan_infinity", json.dumps(obj).encode())

    def _c_hostile_start_params(self) -> FuzzCase:
        r = self.rng
        bad: list[dict[str, Any]] = [
            {"speed": 3},
            {"mode": "evaluate", "__class__": {}},
            {"mode": "debug"},
            {"mode": ["collect"]},
            {"mode": {"collect": True}},
            {"mode": "collect"},
            {"mode": "collect", "label": "grimy"},
            {"mode": "collect", "label": ["dirty"]},
            {"surface": "top"},
            {"surface": None},
            {"perturb_m": -0.01},
            {"perturb_m": 0.5},
            {"perturb_m": 1e308},
            {"perturb_m": "0.01"},
            {"perturb_m": True},
            {"perturb_m": [0.01]},
            {"seed": -1},
            {"seed": 1.5},
            {"seed": True},
            {"seed": "7"},
            {"seed": 2**63},
            {"seed": 10**200},
            {"dataset": {"path": "/tmp"}},
            {"dataset": 42},
            {"dataset": ""},
            {"dataset": ["a", "b"]},
            {self._text(5): self._value()},
        ]
        params = dict(r.choice(bad))
        if r.random() < 0.3:  # a valid-looking key alongside
            params.setdefault("surface", "external")
        obj = {"type": _CMD, "v": 1, "request_id": self._rid(), "params": params}
        obj.update({"command": "start"} if r.random() < 0.5 else {"cntrl_cmd": 2})
        return FuzzCase("hostile_start_params", json.dumps(obj).encode())

    def _c_params_on_other_commands(self) -> FuzzCase:
        r = self.rng
        obj = self._valid(r.choice([n for n in NAMES if n != "start"]))
        obj["params"] = r.choice([{"mode": "evaluate"}, {"force": True}, {"x": self._value()}])
        return FuzzCase("params_on_other_commands", json.dumps(obj).encode())

    def _c_duplicate_keys(self) -> FuzzCase:
        r = self.rng
        a, b = r.choice(NAMES), r.choice(NAMES)
        dup = r.choice(
            [
                f'"command":"{a}","command":"{b}"',
                f'"command":"{a}","cntrl_cmd":null,"cntrl_cmd":{PackMLCommand[b].value}',
                f'"type":"cellctl/Status","type":"{_CMD}","command":"{a}"',
                f'"v":2,"v":1,"command":"{a}"',
                f'"command":"{a}","params":{{"seed":1,"seed":-1}}',
            ]
        )
        head = '"type":"cellctl/Command","v":1,' if '"type"' not in dup else ""
        return FuzzCase("duplicate_keys", ("{" + head + dup + "}").encode())

    def _c_bom_and_encodings(self) -> FuzzCase:
        r = self.rng
        text = json.dumps(self._valid())
        payload = r.choice(
            [
                b"\xef\xbb\xbf" + text.encode(),
                text.encode("utf-16"),
                text.encode("utf-16-le"),
                text.encode("utf-32"),
                text.encode("utf-16-be"),
            ]
        )
        return FuzzCase("bom_and_encodings", payload)

    def _c_valid(self) -> FuzzCase:
        r = self.rng
        obj = self._valid(rid=r.random() < 0.8)
        text = json.dumps(obj, separators=r.choice([(",", ":"), (", ", ": ")]), indent=r.choice([None, 2]))
        return self._expect_valid("valid", obj, (r.choice(["", " ", "\n"]) + text + r.choice(["", "\n"])).encode())

    # --- the stream ---------------------------------------------------------------------------

    def next_case(self) -> FuzzCase:
        """One case; valid commands are about a sixth of the stream so the machine keeps moving."""
        r = self.rng
        if r.random() < 0.15:
            return self._c_valid()
        return self._gens[r.choice(CATEGORIES_HOSTILE)]()

    def cases(self, n: int) -> Iterator[FuzzCase]:
        for _ in range(n):
            yield self.next_case()


CATEGORIES_HOSTILE = tuple(
    sorted(n[len("_c_") :] for n in dir(CommandFuzzer) if n.startswith("_c_") and n != "_c_valid")
)
CATEGORIES = (*CATEGORIES_HOSTILE, "valid")
"""Every category a case can come from."""


# --- the target: a running cell, a client session, the slowed sim robot -------------------------


@contextmanager
def slow_sim_robot(cfg: Any) -> Iterator[None]:
    """Run the sim robot worker (in a thread of this process) for the fuzzed cell.

    Raises:
        CellError: its liveliness token does not appear within 30 s.
    """
    from cellctl.workers.robot import run_worker

    stop = threading.Event()
    t = threading.Thread(target=run_worker, args=(cfg, "sim", stop), name="fuzz-robot", daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join(30)


class _ErrorLogs(logging.Handler):
    """Counts ERROR records of the supervisor: a dispatcher or step crash logs one."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.records: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(f"{record.name}: {record.getMessage()}")


@dataclass
class FuzzStats:
    """What a run sent and what came back (JSON-able via :meth:`as_dict`)."""

    seed: int
    sent: Counter = field(default_factory=Counter)
    accepted: Counter = field(default_factory=Counter)
    rejected: Counter = field(default_factory=Counter)
    via: Counter = field(default_factory=Counter)
    by_state: Counter = field(default_factory=Counter)
    acks: int = 0
    driver_commands: int = 0
    violations: list[str] = field(default_factory=list)
    n_violations: int = 0

    def violation(self, case: FuzzCase | None, text: str) -> None:
        self.n_violations += 1
        if len(self.violations) < 20:
            where = f"[{case.category}] {case.payload[:80]!r}: " if case is not None else ""
            self.violations.append(where + text)

    def as_dict(self) -> dict[str, Any]:
        return {
            "seed": self.seed,
            "cases": sum(self.sent.values()),
            "acks": self.acks,
            "accepted": sum(self.accepted.values()),
            "rejected": sum(self.rejected.values()),
            "violations": self.n_violations,
            "violation_examples": self.violations,
            "by_category": {
                c: {"sent": self.sent[c], "accepted": self.accepted[c], "rejected": self.rejected[c]}
                for c in sorted(self.sent)
            },
            "by_transport": dict(sorted(self.via.items())),
            "cases_by_state": dict(sorted(self.by_state.items())),
            "driver_commands": self.driver_commands,
        }


class FuzzTarget:
    """Sends fuzz cases to a running cell and checks the command contract on each.

    Args:
        cell: a :class:`cellctl.app.Cell` built in this process (the checks read its supervisor's
            state directly, besides asking over the bus).
        timeout: seconds to wait for an Ack or a status reply.
    """

    def __init__(self, cell: Any, timeout: float = 5.0, seed: int = 0) -> None:
        from cellctl.bus.session import open_session

        self.cell = cell
        self.sup = cell.supervisor
        self.cfg = cell.cfg
        self.timeout = timeout
        self.stats = FuzzStats(seed)
        self.rng = random.Random(seed + 1)
        c = self.cfg.cell_id
        self.key = keys.cmd(c)
        self.session = open_session(self.cfg, "client")
        self._acks: queue.Queue[bytes] = queue.Queue()
        self._sub = self.session.declare_subscriber(keys.cmd_ack(c), lambda s: self._acks.put(s.payload.to_bytes()))
        self._errors = _ErrorLogs()
        logging.getLogger("cellctl.supervisor").addHandler(self._errors)
        deadline = time.monotonic() + 30
        while not all(self.sup.status.workers.get(r) for r in self.cfg.supervisor.required_workers):
            if time.monotonic() > deadline:
                raise CellError(
                    f"required workers {self.cfg.supervisor.required_workers} not alive within 30 s "
                    "(run the cell inside slow_sim_robot)"
                )
            time.sleep(0.02)
        self._visits: Counter = Counter()

    # --- helpers ------------------------------------------------------------------------------

    def status_state(self) -> str | None:
        """The state a status query reports, or None when nothing answers (dispatcher dead)."""
        from cellctl.messages import Status

        replies = list(self.session.get(keys.status(self.cfg.cell_id), timeout=self.timeout))
        if len(replies) != 1 or replies[0].ok is None:
            return None
        return decode_as(Status, replies[0].ok.payload.to_bytes()).state

    def settle(self) -> str:
        """Wait until the machine rests in a :data:`STABLE` state; return the full state name."""
        deadline = time.monotonic() + 10
        while True:
            st = self.sup.state
            if st in STABLE:
                break
            if time.monotonic() > deadline:
                self.stats.violation(None, f"machine did not come to rest within 10 s (in {st})")
                break
            time.sleep(0.001)
        # A status round trip: every event queued before it (done, Ack) has been dispatched.
        if self.status_state() is None:
            self.stats.violation(None, "status query unanswered: dispatcher dead?")
        return self.sup.state

    def _ack(self, case: FuzzCase, via: str) -> Ack | None:
        if via == "query":
            replies = list(self.session.get(self.key, payload=case.payload, timeout=self.timeout))
            if len(replies) != 1:
                self.stats.violation(case, f"query got {len(replies)} replies, expected exactly one Ack")
                return None
            if replies[0].ok is None:
                self.stats.violation(case, f"query got an error reply: {replies[0].err.payload.to_bytes()[:200]!r}")
                return None
            data = replies[0].ok.payload.to_bytes()
        else:
            self.session.put(self.key, case.payload)
            try:
                data = self._acks.get(timeout=self.timeout)
            except queue.Empty:
                self.stats.violation(case, f"no Ack on cmd/ack within {self.timeout:g} s")
                return None
        try:
            return decode_as(Ack, data)
        except CellError as err:
            self.stats.violation(case, f"reply is not an Ack: {err}")
            return None

    # --- one case -----------------------------------------------------------------------------

    def send(self, case: FuzzCase, via: str = "query", *, count: bool = True) -> Ack | None:
        """Send one case by ``query`` or ``put`` and check the contract; return the Ack.

        ``count=False``: checked like any case but left out of the counts (driver commands).
        """
        st = self.stats
        before = self.settle()
        top = before.split(".", 1)[0]
        allowed = self.sup.packml.allowed_commands(top)
        while not self._acks.empty():
            self._acks.get_nowait()
            st.violation(case, "an extra Ack arrived on cmd/ack before this case")
        n_errors = len(self._errors.records)
        if count:
            st.sent[case.category] += 1
            st.via[via] += 1
            st.by_state[top] += 1
        ack = self._ack(case, via)
        if ack is not None:
            if count:
                st.acks += 1
                (st.accepted if ack.accepted else st.rejected)[case.category] += 1
            self._check(case, ack, before, top, allowed)
        for rec in self._errors.records[n_errors:]:
            st.violation(case, f"supervisor logged an error: {rec[:300]}")
        return ack

    def _check(self, case: FuzzCase, ack: Ack, before: str, top: str, allowed: list[str]) -> None:
        st = self.stats
        if case.expect is not None and case.expect != REJECT and ack.request_id != case.request_id:
            st.violation(case, f"Ack request_id {ack.request_id!r}, sent {case.request_id!r}")
        if not ack.accepted:
            if not ack.reason:
                st.violation(case, "rejecting Ack without a reason")
            if ack.state != top:
                st.violation(case, f"rejecting Ack says state {ack.state!r}, machine was in {top!r}")
            if case.expect not in (None, REJECT) and case.expect in allowed:
                st.violation(case, f"valid {case.expect!r} rejected in {top}: {ack.reason}")
            if self.status_state() is None:
                st.violation(case, "status query unanswered after a rejected command")
            if self.sup.state != before:
                st.violation(case, f"state changed {before} -> {self.sup.state} on a rejected command")
            return
        if case.expect == REJECT:
            st.violation(case, f"accepted ({ack.command} in {top}) a payload that must be refused")
        elif case.expect is not None and ack.command != case.expect:
            st.violation(case, f"accepted as {ack.command!r}, sent {case.expect!r}")
        if ack.command not in allowed:
            st.violation(case, f"accepted {ack.command!r} in {top}; allowed: {allowed}")
        self._visits[self.settle().split(".", 1)[0]] += 1

    def drive(self) -> None:
        """Send one allowed command, favouring the least visited destination, so every state gets fuzzed."""
        top = self.settle().split(".", 1)[0]
        allowed = self.sup.packml.allowed_commands(top)
        dest = self.sup.packml.commands
        # the waiting state each command leads to, through its acting state
        rest = self.sup.packml.state_complete
        score = {c: self._visits[rest.get(dest[c][top], dest[c][top])] + self.rng.random() for c in allowed}
        name = min(score, key=score.__getitem__)
        msg = Command(command=name, request_id=f"drive-{self.stats.driver_commands}")
        self.stats.driver_commands += 1
        self.send(FuzzCase("driver", encode(msg), name, msg.request_id), count=False)

    def finish(self) -> None:
        """Final checks (no late Ack, dispatcher alive), then close the client side."""
        time.sleep(0.2)
        if not self._acks.empty():
            self.stats.violation(None, "an extra Ack arrived after the last case")
        if self.status_state() is None or self.sup.wait_stopped(0):
            self.stats.violation(None, "the supervisor's dispatcher is not answering at the end")
        logging.getLogger("cellctl.supervisor").removeHandler(self._errors)
        self._sub.undeclare()
        self.session.close()


def run_fuzz(
    cell: Any, n: int, seed: int, *, drive_every: int = 20, progress: Callable[[int, int], None] | None = None
) -> dict[str, Any]:
    """Send ``n`` seeded cases to ``cell`` (half by query, half by put) and return the counts.

    Every ``drive_every`` cases one allowed command moves the machine on (not counted as a case).
    """
    fuzzer = CommandFuzzer(seed, cell.cfg.supervisor.max_command_bytes)
    target = FuzzTarget(cell, seed=seed)
    t0 = time.perf_counter()
    try:
        for i, case in enumerate(fuzzer.cases(n)):
            if i % drive_every == 0:
                target.drive()
            target.send(case, "query" if fuzzer.rng.random() < 0.5 else "put")
            if progress is not None and ((i + 1) % 500 == 0 or i + 1 == n):
                progress(i + 1, n)
    finally:
        target.finish()
    dt = time.perf_counter() - t0
    out = target.stats.as_dict()
    out["seconds"] = round(dt, 2)
    out["cases_per_s"] = round(n / dt, 1) if dt > 0 else None
    return out


def bench_fuzz(args: argparse.Namespace) -> dict[str, Any]:
    """``cellctl bench fuzz``: a real cell on a private loopback port, ``--n`` cases from ``--seed``."""
    from cellctl.app import build_cell
    from cellctl.bus.session import private_bus_overrides
    from cellctl.config import load_config, output_overrides

    n = args.n or 10_000
    tmp = tempfile.mkdtemp(prefix="cellctl-bench-fuzz-")
    cfg = load_config(args.config, [*args.overrides, *private_bus_overrides(), *output_overrides(tmp), *FUZZ_OVERRIDES])
    try:
        # No identification: the cycle never gets past approaching (no vision imports needed).
        with build_cell(cfg, identification=(None, None)) as cell, slow_sim_robot(cfg):
            out = run_fuzz(
                cell, n, args.seed, progress=lambda i, k: print(f"bench fuzz {i}/{k}", file=sys.stderr, flush=True)
            )
            out["cycles_opened"] = len(cell.index.all())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out["target"] = "cell/<id>/cmd: zenoh tcp loopback, daemon router in this process, client session; sim robot"
    out["max_command_bytes"] = cfg.supervisor.max_command_bytes
    return out
