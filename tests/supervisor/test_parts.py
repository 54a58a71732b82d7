"""The supervisor's parts on their own, without Zenoh: command checks, roster, runner, recorder,
outbox, admin counters, behaviours, machine and the loader's data-flow check."""

from __future__ import annotations

import json
import queue
import threading
from pathlib import Path

import pytest
import zenoh
from mcap.reader import make_reader

from cellctl.bus.codec import encode
from cellctl.errors import ConfigError, WorkerUnavailable
from cellctl.messages import Ack, Command, CycleOutcome, CycleResult, StartParams, UnitMode
from cellctl.supervisor.admin import AdminBook
from cellctl.supervisor.behaviours import BEHAVIOUR_CLASSES, BEHAVIOURS, FinishCycle, OpenCycle, behaviour
from cellctl.supervisor.commands import Accepted, check_command, recorded_command
from cellctl.supervisor.context import INITIAL_CONTEXT, Cancelled
from cellctl.supervisor.context.identity import Identity
from cellctl.supervisor.context.result import Result
from cellctl.supervisor.cycles import CycleKeeper
from cellctl.supervisor.definition import StepIO, load_cycle
from cellctl.supervisor.events import StepDone
from cellctl.supervisor.machine import CellModel, build_machine
from cellctl.supervisor.publisher import Outbox, make_status
from cellctl.supervisor.recorder import CycleRecorder, NullRecorder, assemble_result
from cellctl.supervisor.registry import STEP_IO, load_definitions
from cellctl.supervisor.roster import WorkerRoster
from cellctl.supervisor.runner import Runner
from cellctl.supervisor.steps import STEPS
from tests.supervisor._scripted import context, index

PACKML, CYCLE = load_definitions()


def _check(payload: bytes, state: str = "Idle", mode: UnitMode = UnitMode.production) -> Accepted | Ack:
    return check_command(payload, max_bytes=65536, state=state, allowed=PACKML.allowed_commands(state), mode=mode)


# --- command checks -------------------------------------------------------------------------


def test_a_valid_start_is_accepted_with_typed_params() -> None:
    out = _check(encode(Command(command="start", params={"mode": "collect", "label": "dirty", "seed": 3})))
    assert isinstance(out, Accepted)
    assert out.start == StartParams(mode="collect", label="dirty", seed=3)
    ack = out.ack("Starting", UnitMode.production)
    assert ack.accepted and ack.command == "start" and ack.unit_mode == "production"


@pytest.mark.parametrize(
    "params, reason",
    [
        (
            {"speed": 3},
            "unknown start params ['speed']; allowed: ['dataset', 'label', 'mode', 'perturb_m', 'seed', 'surface']",
        ),
        (
            {"mode": "fast"},
            "start param mode='fast'; expected 'evaluate', 'collect', 'wash_and_verify' or 'commission'",
        ),
        ({"mode": "collect"}, "start param label=None; collect mode needs label 'clean' or 'dirty'"),
        ({"surface": "top"}, "start param surface='top'; expected 'external' or 'internal'"),
        ({"perturb_m": 0.5}, "start param perturb_m=0.5; expected a number in [0, 0.1] m"),
        ({"seed": -1}, "start param seed=-1; expected an integer in [0, 2**63)"),
        ({"seed": True}, "start param seed=True; expected an integer in [0, 2**63)"),
    ],
)
def test_bad_start_params_are_refused_naming_the_value(params: dict, reason: str) -> None:
    out = _check(encode(Command(command="start", request_id="r", params=params)))
    assert isinstance(out, Ack) and not out.accepted
    assert out.reason == reason and out.request_id == "r" and out.state == "Idle"


@pytest.mark.parametrize(
    "obj",
    [
        {"v": 1, "command": "reset", "request_id": "plc-7"},  # type missing
        {"type": "cellctl/Status", "v": 1, "request_id": "plc-7"},  # wrong type
        {"type": "cellctl/Command", "request_id": "plc-7", "command": "reset"},  # v missing
        {"type": "cellctl/Command", "v": 2, "request_id": "plc-7", "command": "reset"},  # wrong v
        {"type": "cellctl/Command", "v": "1", "request_id": "plc-7"},
        {"type": "cellctl/Command", "v": 1, "request_id": "plc-7", "command": "jump"},
    ],
)
def test_a_rejected_command_echoes_a_readable_request_id(obj: dict) -> None:
    out = _check(json.dumps(obj).encode())
    assert isinstance(out, Ack) and not out.accepted
    assert out.request_id == "plc-7"


@pytest.mark.parametrize(
    "payload",
    [b"{not json", b'{"request_id": 7}', b'{"request_id": ["x"]}', b'["plc-7"]', b'{"request_id": "\\ud800"}',
     json.dumps({"request_id": "x" * 129}).encode(), b"x" * 70000],
)  # fmt: skip
def test_no_request_id_is_echoed_when_none_can_be_read(payload: bytes) -> None:
    out = _check(payload)
    assert isinstance(out, Ack) and out.request_id is None and not out.accepted


def test_params_on_another_command_are_refused() -> None:
    out = _check(encode(Command(command="stop", params={"x": 1})))
    assert isinstance(out, Ack) and out.reason == "command 'stop' takes no params, got ['x']"


def test_the_log_keeps_a_command_as_sent_and_garbage_as_text() -> None:
    raw = encode(Command(command="reset", user="hmi:alice"))
    assert recorded_command(raw) == ("cellctl/Command", raw)
    schema, obj = recorded_command(b"\xff" * 2000)
    assert schema == "cellctl.RejectedPayload" and obj["bytes"] == 2000 and len(obj["raw"]) == 1024


def test_user_is_echoed_and_must_be_printable() -> None:
    out = _check(encode(Command(command="reset", user="opcua:plc")), state="Stopped")
    assert isinstance(out, Accepted) and out.ack("Resetting").user == "opcua:plc"
    bad = _check(b'{"type":"cellctl/Command","v":1,"command":"reset","user":"a\\u0007b","request_id":"q"}', "Stopped")
    assert isinstance(bad, Ack) and "must be printable" in bad.reason and bad.request_id == "q"
    too_long = {"type": "cellctl/Command", "v": 1, "command": "reset", "user": "u" * 65}
    long = _check(json.dumps(too_long).encode(), "Stopped")
    assert isinstance(long, Ack) and "user" in long.reason


# --- roster ---------------------------------------------------------------------------------


def test_roster_counts_tokens_per_role_and_trusts_the_router() -> None:
    answers: queue.Queue[dict[str, int]] = queue.Queue()
    r = WorkerRoster("cell1", ["robot", "camera"], answers.get_nowait)
    assert r.changed("cell/cell1/alive/robot", True) == "robot"
    assert r.changed("cell/cell1/alive/robot", True) == "robot"
    assert r.changed("cell/cell1/alive/supervisor", True) is None
    assert r.changed("cell/other/alive/robot", True) is None
    r.changed("cell/cell1/alive/robot", False)
    assert r.count("robot") == 1 and not r.lost("robot")
    r.changed("cell/cell1/alive/robot", False)
    r.changed("cell/cell1/alive/robot", False)  # a late DELETE never makes the count negative
    assert r.count("robot") == 0 and r.lost("robot")
    assert not r.sync({"robot": 0}) and r.sync({"robot": 1, "camera": 2})
    assert r.workers()["camera"] is True
    answers.put({"robot": 1})
    seen: list[dict[str, int]] = []
    assert r.missing(seen.append) == ["camera"] and seen == [{"robot": 1}]
    assert r.missing() == []  # the query failed (empty queue): the counts the events gave


# --- runner ---------------------------------------------------------------------------------


def test_runner_reports_outcomes_failures_and_ignores_a_cancelled_run(cfg) -> None:
    done: queue.Queue[StepDone] = queue.Queue()
    runner = Runner(done.put)
    ctx = context(cfg)
    runner.cancel()
    runner.launch("a", ctx, lambda run: "succeeded")
    ev = done.get(timeout=5)
    assert ev == StepDone(runner.token, "succeeded") and runner.finished(ev)

    def refuse(run):
        raise WorkerUnavailable("no robot")

    runner.cancel()
    runner.launch("b", ctx, refuse)
    assert done.get(timeout=5) == StepDone(runner.token, "failed", "no robot")
    runner.cancel()
    runner.launch("c", ctx, lambda run: 1 / 0)
    assert done.get(timeout=5).reason == "internal error in c: ZeroDivisionError: division by zero"

    gate = threading.Event()

    def slow(run):
        gate.wait(5)
        return "late"

    runner.cancel()
    runner.launch("d", ctx, slow)
    stale = runner.token
    runner.cancel()  # a state change
    gate.set()
    ev = done.get(timeout=5)
    assert ev.token == stale and not runner.finished(ev)

    def checkpointed(run):
        run.cancelled.wait(5)
        run.checkpoint()

    runner.cancel()
    run = runner.launch("e", ctx, checkpointed)
    runner.cancel()
    with pytest.raises(Cancelled):
        run.checkpoint()
    with pytest.raises(queue.Empty):
        done.get(timeout=0.3)  # a cancelled run reports nothing


# --- recorder, cycle keeper, admin ----------------------------------------------------------


def test_cycle_recorder_writes_the_row_first_and_a_readable_mcap(cfg, tmp_path: Path) -> None:
    import datetime as dt

    idx = index(tmp_path)
    now = dt.datetime(2026, 1, 2, 3, 4, 5, 6000, tzinfo=dt.UTC)
    rec = CycleRecorder(cfg, idx, "c-1", now, "evaluate")
    assert idx.get("c-1").outcome is None and rec.rel.endswith("2026-01-02/c-1.mcap")
    ctx = context(cfg, log=rec, log_rel=rec.rel, identity=Identity(bin_type="case_study"))
    ctx.result.outcome = CycleOutcome.completed
    ctx.result.verdict = "clean"
    res = assemble_result(ctx, CycleOutcome.aborted)
    assert res.outcome == "completed" and res.verdict == "clean" and res.log == rec.rel
    rec.close(res)
    row = idx.get("c-1")
    assert row.outcome == "completed" and row.verdict == "clean" and row.log_sha256
    with open(rec.path, "rb") as f:
        topics = [ch.topic for _, ch, _ in make_reader(f).iter_messages()]
    assert topics == ["cell/cell1/result"]
    idx.close()


def test_the_verdict_is_kept_only_for_a_completed_cycle(cfg) -> None:
    ctx = context(cfg, result=Result(verdict="dirty"))
    assert assemble_result(ctx, CycleOutcome.aborted).verdict is None


def test_null_recorder_keeps_nothing(cfg) -> None:
    rec = NullRecorder()
    rec.write_json("/x", "s", {"a": 1})
    rec.close(CycleResult(cycle_id="x", outcome=CycleOutcome.aborted))
    assert rec.path is None and rec.rel is None


def test_admin_counts_from_the_index_and_from_finished_cycles(cfg, tmp_path: Path) -> None:
    idx = index(tmp_path)
    for cid, outcome, verdict in [("a", "completed", "clean"), ("b", "completed", "dirty"), ("c", "aborted", None)]:
        idx.begin(cid, "cell1", f"/tmp/{cid}.mcap")
        idx.finish(cid, outcome, verdict=verdict, finished="2026-01-01T00:00:00.000+00:00")
    book = AdminBook(idx)
    snap = book.snapshot(["planner worker not alive"])
    assert (snap.prod_processed_count, snap.prod_defective_count) == (2, 1)
    assert snap.last_cycle.cycle_id == "c" and snap.warnings == ["planner worker not alive"]
    book.cycle_finished(CycleResult(cycle_id="d", outcome=CycleOutcome.completed, verdict="dirty", coverage=0.5))
    snap = book.snapshot()
    assert (snap.prod_processed_count, snap.prod_defective_count) == (3, 2)
    assert snap.last_cycle.coverage == 0.5
    book.warn("stop", "robot stop not confirmed")
    assert book.snapshot([f"w{i}" for i in range(30)]).warnings == [f"w{i}" for i in range(20)]
    idx.close()


class _FakeSession:
    def __init__(self) -> None:
        self.declared: dict[str, dict] = {}
        self.puts: list[tuple[str, bytes]] = []

    def declare_publisher(self, key: str, **kw: object) -> object:
        self.declared[key] = kw
        session = self

        class Pub:
            def put(self, payload: bytes) -> None:
                session.puts.append((key, payload))

            def undeclare(self) -> None:
                pass

        return Pub()


def test_outbox_declares_acks_results_and_events_so_they_are_never_dropped() -> None:
    s = _FakeSession()
    out = Outbox(s, "cell1")
    out.ack(Ack(request_id="x", accepted=True, state="Idle"), None)
    assert s.puts == []  # not declared: a no-op
    out.declare()
    must = {"congestion_control": zenoh.CongestionControl.BLOCK, "reliability": zenoh.Reliability.RELIABLE}
    for key in ("cell/cell1/cmd/ack", "cell/cell1/result", "cell/cell1/events"):
        assert s.declared[key] == must, key
    out.ack(Ack(request_id="x", accepted=True, state="Idle"), None)
    out.announce("warning", "robot left", None, None)
    assert [k for k, _ in s.puts] == ["cell/cell1/cmd/ack", "cell/cell1/events"]


def test_make_status_splits_the_state_and_carries_mode_and_admin() -> None:
    st = make_status(
        "cell1", "Execute.scanning", cycle_id="c", available=["stop"], last_error=None, workers={},
        mode=UnitMode.manual, admin=AdminBook().snapshot(),
    )  # fmt: skip
    assert (st.state, st.state_code, st.step) == ("Execute", 6, "scanning")
    assert (st.unit_mode, st.unit_mode_code) == ("manual", 3)


# --- behaviours and the machine -------------------------------------------------------------


def test_behaviours_table_is_the_registry() -> None:
    assert set(BEHAVIOURS) == set(BEHAVIOUR_CLASSES)
    named = {s.behaviour for s in PACKML.states.values() if s.behaviour}
    assert named <= set(BEHAVIOURS)
    with pytest.raises(ValueError, match="behaviour 'open_cycle' is registered twice"):
        behaviour(type("Again", (OpenCycle,), {}))


class _Host:
    def __init__(self, cfg, tmp_path: Path, missing: list[str]) -> None:
        self.cycles = CycleKeeper(cfg, None, index(tmp_path), Outbox(None, "cell1"), AdminBook(), lambda: False)
        self._missing = missing
        self.resets = 0

    def missing_workers(self) -> list[str]:
        return self._missing

    def reset_cell(self) -> None:
        self.resets += 1


def test_open_cycle_refuses_without_required_workers(cfg, tmp_path: Path) -> None:
    host = _Host(cfg, tmp_path, ["robot", "camera"])
    with pytest.raises(WorkerUnavailable, match="no robot, camera worker alive"):
        OpenCycle().execute(None, host)  # type: ignore[arg-type]
    host._missing = []
    OpenCycle().execute(None, host)  # type: ignore[arg-type]


def test_finish_cycle_early_closes_the_cycle_as_aborted(cfg, tmp_path: Path) -> None:
    host = _Host(cfg, tmp_path, [])
    ctx = host.cycles.open()
    FinishCycle().execute(None, host)  # type: ignore[arg-type]
    res = host.cycles.results[-1]
    assert ctx.finished and res.outcome == "aborted" and res.reason == "completed by command before the cycle ended"
    assert host.cycles.admin.processed == 0
    assert host.cycles.finalize(CycleOutcome.completed) is None  # once only


def test_machine_nests_the_cycle_and_resumes_the_saved_step() -> None:
    model = CellModel()
    saved: list[str | None] = [None]
    build_machine(PACKML, CYCLE, model, lambda: saved[0], lambda: None)
    assert model.state == "Stopped" and model.top == "Stopped" and model.step is None
    for t in ("reset", "sc", "start", "sc"):
        model.trigger(t)
    assert model.state == "Execute.approaching" and model.step == "approaching"
    model.trigger("step_succeeded")
    assert model.state == "Execute.identifying"
    saved[0] = "identifying"
    for t in ("hold", "sc", "unhold", "sc"):
        model.trigger(t)
    assert model.state == "Execute.identifying"


# --- the loader's data-flow check -----------------------------------------------------------


def _cycle_yaml(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "cycle.yaml"
    p.write_text(text)
    return p


def test_loader_refuses_a_step_whose_reads_nobody_writes(tmp_path: Path) -> None:
    io = {**STEP_IO, "weighing": StepIO(reads=frozenset({"bin_mass_kg"}), writes=frozenset())}
    outcomes = {**{k: v.OUTCOMES for k, v in STEPS.items()}, "weighing": ("succeeded",)}
    path = _cycle_yaml(
        tmp_path,
        "initial: approaching\nstates:\n"
        "  approaching: {step: approaching, on: {succeeded: weighing, failed: {exit: abort}}}\n"
        "  weighing: {step: weighing, on: {succeeded: {exit: complete}}}\n",
    )
    with pytest.raises(ConfigError) as exc:
        load_cycle(path, outcomes, io, INITIAL_CONTEXT)
    assert str(exc.value) == (
        f"{path}: states.weighing: step 'weighing' reads ['bin_mass_kg'], which no step writes on every path from"
        " 'approaching' to it (nor does the cycle's initial context provide it)"
    )


def test_loader_refuses_a_read_written_on_only_one_path(tmp_path: Path) -> None:
    """identifying's failure leads to scanning too: on that path nobody wrote the plan."""
    outcomes = {k: v.OUTCOMES for k, v in STEPS.items()}
    text = (
        "initial: approaching\nstates:\n"
        "  approaching: {step: approaching, on: {succeeded: identifying, failed: {exit: abort}}}\n"
        "  identifying: {step: identifying, on: {succeeded: checking_cache, retry: approaching, failed: scanning}}\n"
        "  checking_cache: {step: checking_cache, on: {hit: scanning, miss: {exit: complete}, move: {exit: abort},"
        " failed: {exit: abort}}}\n"
        "  scanning: {step: scanning, on: {succeeded: {exit: complete}, failed: {exit: abort}}}\n"
    )
    with pytest.raises(ConfigError, match=r"states.scanning: step 'scanning' reads \['scan.plan'\]"):
        load_cycle(_cycle_yaml(tmp_path, text), outcomes, STEP_IO, INITIAL_CONTEXT)


def test_the_shipped_cycle_passes_the_data_flow_check() -> None:
    assert (
        load_cycle(None, {k: v.OUTCOMES for k, v in STEPS.items()}, STEP_IO, INITIAL_CONTEXT).initial == "approaching"
    )
