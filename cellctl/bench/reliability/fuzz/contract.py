"""The command contract, checked on every case sent to a running cell.

:class:`FuzzTarget` sends a :class:`~cellctl.bench.reliability.fuzz.generators.FuzzCase` by query or
by put and records in :class:`FuzzStats` every breach of: exactly one Ack per command; a
rejected command changes nothing and names the state it arrived in; a payload that must be
refused is refused; a valid command is accepted exactly when the PackML table allows it; the
dispatcher stays alive and logs no error.
"""

from __future__ import annotations

import logging
import queue
import random
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from cellctl.bench.reliability.fuzz.generators import REJECT, FuzzCase
from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.errors import CellError
from cellctl.messages import Ack, Command

__all__ = ["STABLE", "FuzzStats", "FuzzTarget"]

STABLE = frozenset({"Stopped", "Idle", "Held", "Suspended", "Complete", "Aborted", "Execute.approaching"})
"""States the machine stays in without a command (Execute: the slowed robot never finishes parking)."""


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
        # a raw session on purpose, not PlcClient: the fuzzer sends malformed and hand-built payloads, and its
        # driver's valid commands take the same path so every Ack is matched the same way
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
