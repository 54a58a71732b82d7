"""Read recorded cycles back: republish them on Zenoh (rosbag2-style ``play``) or re-run the
supervisor against the recorded worker replies (``verify``, a regression test for logs).

Reading is tolerant: a truncated file (a crash mid-cycle) yields every message up to the
damage and says what was skipped (``cellctl recover`` writes such a file's valid copy; an
interrupted cycle's copy is made when the supervisor restarts); a file that is not MCAP, or
that holds a message of a newer schema version than this cellctl speaks, is refused with a
clear error.
"""

from __future__ import annotations

import functools
import json
import logging
import queue
import tempfile
import threading
import time
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from cellctl.bus import topics
from cellctl.errors import RecordingError

if TYPE_CHECKING:
    from cellctl.messages import CycleResult

__all__ = ["RecordedCycle", "RecordedMessage", "read_cycle", "recorded_as_sent", "republish", "verify"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class RecordedMessage:
    topic: str
    schema: str
    log_time: int
    data: bytes

    def json(self) -> Any:
        return json.loads(self.data)


@dataclass
class RecordedCycle:
    path: Path
    messages: list[RecordedMessage] = field(default_factory=list)
    truncated: bool = False
    skipped: str | None = None
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)

    def on(self, topic: str) -> list[RecordedMessage]:
        return [m for m in self.messages if m.topic == topic]

    @property
    def name(self) -> str:
        """The cycle id the log names in its metadata, else the file's stem (a log from elsewhere)."""
        return self.metadata.get("cycle", {}).get("cycle_id") or self.path.stem.removesuffix(".recovered")

    def cells(self) -> list[str]:
        """The cell ids whose keys the log recorded (``cell/<id>/...`` topics)."""
        from cellctl.bus import keys

        return sorted({keys.cell_from_key(t) for t in {m.topic for m in self.messages} if t.startswith("cell/")})


def _is_command(topic: str) -> bool:
    """A recorded topic of a cell's command exchange (``cell/<id>/cmd`` or ``cmd/ack``)."""
    from cellctl.bus import keys
    from cellctl.errors import ConfigError

    try:
        return topic in keys.command_keys(keys.cell_from_key(topic))
    except ConfigError:
        return False  # not a cell key (``/camera/image``)


def read_cycle(path: Path | str) -> RecordedCycle:
    """Read every intact message of a cycle log.

    Raises:
        RecordingError: the file is missing, not MCAP, or holds a newer wire version.
    """
    from cellctl.messages import MESSAGE_TYPES

    p = Path(path)
    try:
        head = p.open("rb").read(len(MCAP_MAGIC))
    except OSError as err:
        raise RecordingError(f"cannot read {str(p)!r}: {err}") from err
    if head != MCAP_MAGIC:
        raise RecordingError(f"{str(p)!r} is not an MCAP file (starts with {head!r}, expected {MCAP_MAGIC!r})")
    out = RecordedCycle(p)
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    with p.open("rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, rec.schema_id)
                elif isinstance(rec, Message):
                    topic, sid = channels[rec.channel_id]
                    out.messages.append(RecordedMessage(topic, schemas.get(sid, ""), rec.log_time, bytes(rec.data)))
                elif type(rec).__name__ == "Metadata":
                    out.metadata[rec.name] = dict(rec.metadata)  # type: ignore[attr-defined]
        except Exception as err:  # a truncated tail (crash) ends the stream with a read error
            out.truncated = True
            out.skipped = f"stopped at byte {f.tell()} of {p.stat().st_size}: {type(err).__name__}: {err}"
    if out.truncated and not out.messages:
        raise RecordingError(
            f"{str(p)!r} holds no readable message ({out.skipped}); not a cycle log, or cut before one"
        )
    for m in out.messages:
        model = MESSAGE_TYPES.get(m.schema)
        if model is None:
            continue
        v = m.json().get("v")
        supported = model.model_fields["v"].default
        if isinstance(v, int) and v > supported:
            raise RecordingError(
                f"{str(p)!r} holds {m.schema} version {v}; "
                f"this cellctl reads up to version {supported} — upgrade cellctl"
            )
    return out


def republish(
    cycle: RecordedCycle,
    session: Any,
    *,
    rate: float = 1.0,
    loop: bool = False,
    start_offset_s: float = 0.0,
    topics: list[str] | None = None,
    prefix: str | None = None,
    live: bool = False,
    stop: threading.Event | None = None,
) -> int:
    """Put the recorded messages on Zenoh with their original spacing (scaled by ``rate``).

    Every message goes to ``prefix`` + its topic without the leading slash; the default prefix is
    ``keys.replay_prefix(cycle.name)`` (``replay/<cycle>/``), outside every cell's keys. ``live``
    publishes on the recorded keys themselves (no prefix), but never a command or an Ack: a replay
    must not drive a cell (the caller checks that no supervisor of the cell is alive).
    Returns how many messages were put.

    Raises:
        RecordingError: ``rate`` is not positive; ``prefix`` with ``live``; or, without ``live``, a
            prefix that would put a message on a cell's keys (``cell/...``).
    """
    from cellctl.bus import keys

    if rate <= 0:
        raise RecordingError(f"rate {rate!r} must be > 0")
    if live and prefix:
        raise RecordingError(f"prefix {prefix!r} and live exclude each other: live publishes on the recorded keys")
    if live:
        prefix = ""
    elif prefix is None:
        prefix = keys.replay_prefix(cycle.name)
    msgs = [m for m in cycle.messages if topics is None or m.topic in topics]
    if live:
        msgs = [m for m in msgs if not _is_command(m.topic)]
    else:
        onto_cell = sorted(_cell_keys(prefix, msgs))
        if onto_cell:
            raise RecordingError(
                f"prefix {prefix!r} would publish on a cell's keys ({onto_cell[0]!r}); use a prefix outside"
                f" cell/ (the default is {keys.replay_prefix(cycle.name)!r}) or the explicit live mode"
            )
    if not msgs:
        return 0
    t_first = msgs[0].log_time + int(start_offset_s * 1e9)
    msgs = [m for m in msgs if m.log_time >= t_first]
    stop = stop or threading.Event()
    sent = 0
    while msgs and not stop.is_set():
        t0 = time.monotonic()
        for m in msgs:
            due = t0 + (m.log_time - t_first) / 1e9 / rate
            if stop.wait(max(0.0, due - time.monotonic())):
                return sent
            key = m.topic.lstrip("/")
            session.put(f"{prefix}{key}", m.data)
            sent += 1
        if not loop:
            break
    return sent


def _cell_keys(prefix: str, msgs: list[RecordedMessage]) -> set[str]:
    """The keys ``prefix`` + topic that land under ``cell/``: a live cell's key space."""
    out = {prefix + m.topic.lstrip("/") for m in msgs}
    return {k for k in out if k.startswith("cell/")}


@dataclass
class VerifyReport:
    ok: bool
    differences: list[str]
    states_recorded: list[str]
    states_replayed: list[str]
    requests: int
    skipped: str | None = None
    interrupted: bool = False
    """The log ends at a crash (no CycleResult): checked up to the cut, the replay aborted there."""

    def as_dict(self) -> dict[str, Any]:
        return self.__dict__ | {}


_VOLATILE = {"stamp", "cycle_id", "log", "started", "finished", "request_id", "timing"}


_GATE_FIELDS = ("coverage_by_surface", "min_seen_fraction")
"""CycleResult fields of the verdict's coverage gate (cellctl.seen); before it, single-station cycles left them null."""

_REFERENCE_FIELDS = ("decision_path", "reference_version", "commission")
"""CycleResult fields that depend on the reference sets on disk when the cycle ran, not on a worker's reply: a
replay runs beside its own empty reference root (it must never add a set to the cell's), so they are not compared."""


def _reference_relative(msg: dict[str, Any]) -> dict[str, Any]:
    """An enroll request with its paths from the reference root on (the replay's root is a scratch folder); a
    classify request without the reference the scan found on disk (the scratch root has none: the recorded
    reply still says which path decided)."""
    if msg.get("type") == "cellctl/ClassifyRequest":
        return {k: v for k, v in msg.items() if k != "reference"}
    if msg.get("type") != "cellctl/EnrollRequest":
        return msg
    cut = {k: str(msg.get(k, "")).rpartition("/references/")[2] for k in ("images", "out")}
    return {**msg, **cut}


def recorded_as_sent(recorded: CycleResult, replayed: CycleResult) -> CycleResult:
    """The recorded CycleResult as the replay's subscriber would have received it.

    The replay reads the replayed result off the bus, where a result past the wire's size comes cut
    (``viewpoints_omitted``; the MCAP keeps every view), so a recorded result that was whole there is
    cut by the same rule before the two are compared.
    """
    from cellctl.bus.codec import decode_as
    from cellctl.messages import CycleResult
    from cellctl.supervisor.publisher import fit_to_wire

    if replayed.viewpoints_omitted and not recorded.viewpoints_omitted:
        return decode_as(CycleResult, fit_to_wire(recorded))
    return recorded


def _strip(obj: Any) -> Any:
    """Drop the fields that legitimately differ between a run and its replay (times, ids)."""
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if k not in _VOLATILE}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    if isinstance(obj, float):
        return round(obj, 6)
    return obj


def _as_today(recorded: dict[str, Any]) -> dict[str, Any]:
    """A recorded request read by today's model: fields added since (still v1) take their defaults."""
    from cellctl.messages import MESSAGE_TYPES

    model = MESSAGE_TYPES.get(str(recorded.get("type")))
    if model is None:
        return recorded
    try:
        return json.loads(model.model_validate(recorded).model_dump_json())
    except ValueError:
        return recorded  # not valid today: compared as recorded, and the difference is reported


def _state_sequence(statuses: list[dict[str, Any]]) -> list[str]:
    seq: list[str] = []
    for st in statuses:
        s = st["state"] + (f".{st['step']}" if st.get("step") else "")
        if not seq or seq[-1] != s:
            seq.append(s)
    return seq


@dataclass
class _Recording:
    """A recorded cycle indexed for its replay: each key's (request, reply) exchanges in order."""

    rec: RecordedCycle
    prefix: str
    by_key: dict[str, deque[tuple[dict, RecordedMessage | None]]]
    images: deque[RecordedMessage]
    in_flight: dict[str, dict]
    """Requests recorded without a reply: in flight when the log was cut."""
    results: list[dict[str, Any]]
    starts: list[dict[str, Any]]
    """The recorded start commands (their params and user start the replayed cycle)."""
    states: list[str]

    @property
    def interrupted(self) -> bool:
        """The log ends at a crash (no CycleResult)."""
        return not self.results


def _index_recording(path: Path | str, cid: str) -> _Recording:
    """Read ``path`` and pair each recorded request with its reply, per key."""
    from cellctl.bus import keys

    rec = read_cycle(path)
    by_key: dict[str, deque[tuple[dict, RecordedMessage | None]]] = defaultdict(deque)
    images = deque(m for m in rec.messages if m.schema == "foxglove.CompressedImage" and m.topic == topics.CAMERA_IMAGE)
    pending: dict[str, dict] = {}
    for m in rec.messages:
        ex = topics.exchange_of(m.topic)
        if ex is None:
            continue
        k, side = ex
        if side == "request":
            pending[k] = m.json()
        else:
            by_key[k].append((pending.pop(k, {}), m))
    results = [m.json() for m in rec.messages if m.schema == "cellctl/CycleResult"]
    commands = [m.json() for m in rec.messages if m.schema == "cellctl/Command" and m.topic == keys.cmd(cid)]
    starts = [c for c in commands if c.get("command") == "start" or c.get("cntrl_cmd") == 2]
    states = _state_sequence([m.json() for m in rec.messages if m.schema == "cellctl/Status"])
    return _Recording(rec, keys.prefix(cid) + "/", by_key, images, dict(pending), results, starts, states)


@dataclass
class _ReplayWorkers:
    """The replay's workers: each request is checked against the recorded one and answered with its reply.

    Handlers run on Zenoh threads: what they share goes under :attr:`lock`.
    """

    recording: _Recording
    differences: list[str]
    lock: threading.Lock = field(default_factory=threading.Lock)
    reached_cut: list[str] = field(default_factory=list)
    """Keys whose requests went past the recording (an interrupted cycle's cut)."""

    def handler(self, key: str) -> Callable[[Any, bytes | None], Any]:
        """The request handler of ``key``."""
        return functools.partial(self.answer, key)

    def answer(self, key: str, req: Any, payload: bytes | None) -> Any:
        from cellctl.bus.codec import decode
        from cellctl.messages import ErrorReply

        r = self.recording
        with self.lock:
            if r.interrupted and not r.by_key[key]:
                # past the recording on this key; other keys go on (classify runs beside scanning)
                want = r.in_flight.pop(key, None)
                self.reached_cut.append(key)
                got = _strip(json.loads(req.model_dump_json()))
                if want is not None and got != _strip(want):
                    self.differences.append(
                        f"the request in flight at the cut on {key} differs: recorded {_strip(want)} replayed {got}"
                    )
                raise RecordingError(f"replay: the recording ends before this request on {key} (interrupted cycle)")
            if not r.by_key[key]:
                raise RecordingError(f"replay: unexpected extra request on {key}")
            want, reply = r.by_key[key].popleft()
        got = _reference_relative(json.loads(req.model_dump_json()))
        want = _reference_relative(_as_today(want))
        if _strip(got) != _strip(want):
            self.differences.append(f"request on {key} differs: recorded {_strip(want)} replayed {_strip(got)}")
        assert reply is not None
        msg = decode(reply.data, 64 * 1024 * 1024)
        if isinstance(msg, ErrorReply):
            # the log holds the supervisor's wording ("robot refused move: <reason>");
            # answer with the worker's own reason so the replayed wording matches
            role, _, op = key[len(r.prefix) :].partition("/")
            said = f"{role} refused {op}: "
            raise RecordingError(msg.reason[len(said) :] if msg.reason.startswith(said) else msg.reason)
        if msg.type == "cellctl/CaptureReply":
            with self.lock:
                img = r.images.popleft().json()["data"] if r.images else ""
            import base64

            return msg, base64.b64decode(img)
        return msg


def _role_ops(r: _Recording, cfg: Any) -> dict[str, list[tuple[str, str]]]:
    """The recorded ops per worker role (every required role, even one the cycle never asked)."""
    role_ops: dict[str, list[tuple[str, str]]] = defaultdict(list)
    for k in r.by_key:
        rest = k[len(r.prefix) :] if k.startswith(r.prefix) else k
        role, _, op = rest.partition("/")
        role_ops[role].append((op, k))
    for role in cfg.supervisor.required_workers:
        role_ops.setdefault(role, [])
    return role_ops


def _config_as_recorded(cfg: Any, rec: RecordedCycle, scratch: Path) -> Any:
    """``cfg`` with what the cycle ran with taken from the log's metadata; plans go to ``scratch``."""
    # Re-looks depend on the config the cycle ran with, not on a reply: take it from the log
    # (a log without the key was recorded before re-looks existed, so it made none).
    relook = cfg.classifier.relook.model_copy(
        update={
            "max_views": int(rec.metadata.get("cycle", {}).get("relook_max_views", 0)),
            "confirm_dirty": rec.metadata.get("cycle", {}).get("relook_confirm_dirty", "off"),
        }
    )
    cfg = cfg.model_copy(update={"classifier": cfg.classifier.model_copy(update={"relook": relook})})
    # so does the station loop (a log without the key was recorded before whole-bin cycles existed)
    whole = rec.metadata.get("cycle", {}).get("whole_bin", "false") == "true"
    planner = cfg.planner.model_copy(
        update={
            "whole": cfg.planner.whole.model_copy(update={"enabled": whole}),
            "plans_dir": scratch / "plans",
        }
    )
    cfg = cfg.model_copy(update={"planner": planner})
    # and the verdict's coverage gate (a log without the key predates it: no minimum)
    minimum = json.loads(rec.metadata.get("cycle", {}).get("min_seen_fraction", "{}"))
    verdict_cfg = cfg.classifier.verdict.model_copy(update={"min_seen_fraction": minimum})
    return cfg.model_copy(update={"classifier": cfg.classifier.model_copy(update={"verdict": verdict_cfg})})


def _serve(session: Any, cid: str, role_ops: dict[str, list[tuple[str, str]]], workers: _ReplayWorkers,
           servers: list[Any]) -> None:  # fmt: skip
    """Announce a replay worker per recorded role, each op answered from the log (appended to ``servers``)."""
    from cellctl.bus import keys
    from cellctl.messages import MESSAGE_TYPES
    from cellctl.workers._server import WorkerServer

    for role, ops in role_ops.items():
        if role not in keys.ROLES:
            continue
        srv = WorkerServer(session, cid, role, "replay" if role == "planner" else None)
        for op, k in ops:
            srv.serve(op.replace("/", "-"), tuple(MESSAGE_TYPES.values()), workers.handler(k), key=k)
        srv.announce()
        servers.append(srv)


def _run_cycle(
    session: Any, cid: str, cell: Any, starts: list[dict[str, Any]], timeout_s: float, differences: list[str]
) -> tuple[CycleResult | None, list[dict]]:
    """Reset the replayed cell, start the cycle as recorded, wait for its result; the statuses it published."""
    from cellctl.bus import keys
    from cellctl.bus.codec import decode_as
    from cellctl.bus.plc_client import PlcClient
    from cellctl.messages import Command, CycleResult, now_iso

    statuses: queue.Queue[dict] = queue.Queue()
    seen: list[dict] = []
    session.declare_subscriber(keys.status(cid), lambda s: statuses.put(json.loads(s.payload.to_bytes())))
    res_q: queue.Queue[CycleResult] = queue.Queue()
    session.declare_subscriber(keys.result(cid), lambda s: res_q.put(decode_as(CycleResult, s.payload.to_bytes())))
    time.sleep(0.3)

    # the commands go as a PLC sends them, through the one client of the contract (ids replay-<token>-<n>)
    plc = PlcClient(cell.cfg, "replay")
    try:
        plc.command("reset", timeout=5)
        deadline = time.monotonic() + 10
        while cell.supervisor.top_state != "Idle" and time.monotonic() < deadline:
            time.sleep(0.02)
        params = starts[0].get("params", {}) if starts else {}
        user = starts[0].get("user") if starts else None
        if params.get("mode") == "commission":  # staff started it in maintenance, signed (unit_modes.py)
            plc.unit_mode("maintenance", timeout=5, user=user)
        while not statuses.empty():
            statuses.get_nowait()
        start = Command(command="start", params=params, user=user, request_id=plc.next_id(), stamp=now_iso())
        ack = plc.send(start, timeout=5)
    finally:
        plc.close()  # the result and the statuses are read on the replay's own session
    if not ack.accepted:
        differences.append(f"start refused on replay: {ack.reason}")
    replayed: CycleResult | None
    try:
        replayed = res_q.get(timeout=timeout_s)
    except queue.Empty:
        differences.append(f"no CycleResult within {timeout_s:g} s")
        replayed = None
    time.sleep(0.2)
    while not statuses.empty():
        seen.append(statuses.get_nowait())
    return replayed, seen


def _compare(
    r: _Recording, replayed: CycleResult | None, seen: list[dict], reached_cut: list[str], differences: list[str]
) -> tuple[list[str], list[str]]:
    """Append what differs (states, result, requests never made) to ``differences``; the two cycles' states."""
    from cellctl.messages import CycleResult

    recorded_states = r.states
    replayed_states = _state_sequence([s for s in seen if s.get("cycle_id")])
    if not any(s.endswith(".next_station") for s in recorded_states):
        # recorded before the station loop's state existed (a single-station cycle passes it at once)
        replayed_states = _state_sequence([s for s in seen if s.get("cycle_id") and s.get("step") != "next_station"])
    outside = ("Idle", "Stopped", "Resetting", "Complete", "Aborted")  # published after the log closed
    rec_cycle_states = [s for s in recorded_states if s.split(".")[0] not in outside]
    rep_cycle_states = [s for s in replayed_states if s.split(".")[0] not in outside]
    if r.interrupted:
        if rec_cycle_states != rep_cycle_states[: len(rec_cycle_states)]:
            differences.append(f"states up to the cut differ: recorded {rec_cycle_states} replayed {rep_cycle_states}")
        if not reached_cut and replayed is not None:
            differences.append(f"the replayed cycle ended ({replayed.outcome}) without reaching the recorded cut")
    elif rec_cycle_states != rep_cycle_states:
        differences.append(f"states differ: recorded {rec_cycle_states} replayed {rep_cycle_states}")
    if not r.interrupted and replayed is not None:
        # The recorded result read by today's model: fields added since (still v1) take their
        # defaults, so a log recorded before them compares on what it holds.
        results = r.results
        want = _strip(json.loads(recorded_as_sent(CycleResult.model_validate(results[-1]), replayed).model_dump_json()))
        got = _strip(json.loads(replayed.model_dump_json()))
        for k in _GATE_FIELDS:  # a log from before the coverage gate holds none: today's replay fills them
            if results[-1].get(k) is None:
                want.pop(k, None)
                got.pop(k, None)
        for k in _REFERENCE_FIELDS:
            want.pop(k, None)
            got.pop(k, None)
        if want != got:
            differences.append(f"result differs: recorded {want} replayed {got}")
    left = {k: len(v) for k, v in r.by_key.items() if v}
    if left:
        differences.append(f"recorded requests never made on replay: {left}")
    return rec_cycle_states, rep_cycle_states


def verify(path: Path | str, cfg: Any, timeout_s: float = 120.0, identification: Any = None) -> VerifyReport:
    """Re-run a recorded cycle through a fresh supervisor whose workers answer from the log.

    The replay workers check that every request equals the recorded one and answer with the
    recorded reply (images included); the supervisor's state sequence and its CycleResult
    must match the recording, times and ids aside.

    An interrupted cycle's log (its recovered copy: no CycleResult) is checked up to the cut:
    every recorded request and the recorded states up to the crash must match, and the first
    request on a key past its recorded replies (the one in flight at the crash, if it was
    logged, must equal it) is answered with an error, and so is every later one on that key;
    what the replayed cycle does past the cut is not compared.
    """
    from cellctl.app import build_cell
    from cellctl.bus.session import open_session

    cid = cfg.cell_id
    r = _index_recording(path, cid)
    differences: list[str] = []
    workers = _ReplayWorkers(r, differences)
    role_ops = _role_ops(r, cfg)
    # reference sets go to a scratch folder: a replayed commissioning must not add a set to the cell's
    scratch = tempfile.TemporaryDirectory(prefix="cellctl-replay-")
    cfg = _config_as_recorded(cfg, r.rec, Path(scratch.name))
    cell = build_cell(cfg, identification=identification)
    session = open_session(cfg, "client")
    servers: list[Any] = []
    try:
        _serve(session, cid, role_ops, workers, servers)
        replayed, seen = _run_cycle(session, cid, cell, r.starts, timeout_s, differences)
    finally:
        for srv in servers:
            srv.close()
        session.close()
        cell.close()
        scratch.cleanup()
    rec_cycle_states, rep_cycle_states = _compare(r, replayed, seen, workers.reached_cut, differences)
    return VerifyReport(
        not differences,
        differences,
        rec_cycle_states,
        rep_cycle_states,
        sum(1 for m in r.rec.messages if m.topic.endswith(topics.REQUEST_SUFFIX)),
        r.rec.skipped,
        r.interrupted,
    )
