"""A plant in one machine: cells, a planner pool and a PLC on separate "hosts" (network namespaces).

Topology (:class:`Cluster`), one Zenoh router per host (``cellctl router``), linked by veths
on 169.254.0.0/16 (:mod:`cellctl.bench.reliability.netns`)::

    cellN host:   cellctl run --with-workers (the cell's router on 127.0.0.1, sim robot/camera/
                  classifier)  +  host router (connects the daemon, the compute and plant hosts)
    compute host: router with the planner pool's job queue + K pool workers (one plans folder)
    plant host:   router + one PLC agent per cell (drives the cell by the wire contract only)

A cell's compute link may run through a :mod:`~cellctl.bench.reliability.relay` (latency, loss).
The PLC agent (:func:`plc_agent_main`) is a process in the plant host that takes JSON
commands on stdin and answers JSON lines on stdout, and logs every Status it receives with
the wall clock (one clock for every namespace), so faults are timed against the cell's own
reports. :func:`bench_cluster` is ``cellctl bench cluster``.
"""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.bench.reliability.netns import Host, Plant, netns_unavailable
from cellctl.bench.reliability.sim_cell import FAST_SIM
from cellctl.errors import CellError, ConfigError

__all__ = ["Cluster", "ClusterOptions", "PlcAgent", "bench_cluster", "plc_agent_main"]

ROUTER_PORT = 7447
HOST_ROUTER_PORT = 7450
RELAY_PORT = 7448
_PY = [sys.executable, "-m", "cellctl"]


@dataclass(frozen=True, kw_only=True)
class ClusterOptions:
    """What plant to build.

    Attributes:
        cells: number of cell hosts (1-3).
        workers: pool workers on the compute host (1-2).
        relayed: cells whose compute link runs through a shaping relay.
        lease_ms: link lease of every router and session (bounds detection).
        cell_overrides: ``--set`` overrides for every cell daemon (after FAST_SIM).
        bin_types: per cell, the bin type its twin inspects (default ``case_study``): cells with
            the same bin type, station pose (bin in the robot base frame) and robot model share
            one plan; another bin type is a cache miss and its own plan.
    """

    cells: int = 1
    workers: int = 1
    relayed: tuple[str, ...] = ()
    lease_ms: int = 2000
    cell_overrides: tuple[str, ...] = ()
    bin_types: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not 1 <= self.cells <= 3:
            raise ConfigError(f"cluster cells={self.cells!r}: expected 1 to 3")
        if not 1 <= self.workers <= 2:
            raise ConfigError(f"cluster workers={self.workers!r}: expected 1 or 2")
        bad = [c for c in self.relayed if c not in self.cell_ids]
        if bad:
            raise ConfigError(f"cluster relayed cells {bad} unknown; cells are {self.cell_ids}")

    @property
    def cell_ids(self) -> list[str]:
        return [f"cell{i + 1}" for i in range(self.cells)]


def _ep(host: str, port: int) -> str:
    return f"tcp/{host}:{port}"


class PlcAgent:
    """The test side of one PLC agent process (JSON lines over its stdin/stdout)."""

    def __init__(self, proc: subprocess.Popen[bytes], cell: str) -> None:
        self.proc, self.cell = proc, cell
        self._lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self._lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for raw in self.proc.stdout:
            try:
                self._lines.put(json.loads(raw))
            except ValueError:
                continue

    def call(self, op: str, timeout: float = 60.0, **args: Any) -> Any:
        """Send one command; its answer (raises CellError with the agent's error)."""
        with self._lock:
            assert self.proc.stdin is not None
            self.proc.stdin.write((json.dumps({"op": op, **args}) + "\n").encode())
            self.proc.stdin.flush()
            try:
                out = self._lines.get(timeout=timeout + 5)
            except queue.Empty:
                raise CellError(f"PLC agent of {self.cell}: no answer to {op!r} within {timeout + 5:g} s") from None
        if "error" in out:
            raise CellError(f"PLC agent of {self.cell}: {op}: {out['error']}")
        return out.get("ok")


@dataclass
class Cluster:
    """Build, run and tear down the plant (a context manager)."""

    opts: ClusterOptions
    tmp: Path
    plant: Plant = field(init=False)
    agents: dict[str, PlcAgent] = field(default_factory=dict)
    procs: dict[str, subprocess.Popen[bytes]] = field(default_factory=dict)

    def __enter__(self) -> Cluster:
        why = netns_unavailable()
        if why is not None:
            raise CellError(f"cannot build the cluster: {why}")
        self.plant = Plant(self.tmp).__enter__()
        try:
            self._build()
        except BaseException:
            self.plant.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        for a in self.agents.values():
            try:
                if a.proc.stdin:
                    a.proc.stdin.close()
            except OSError:
                pass
        self.plant.close()

    # --- building -----------------------------------------------------------------------

    def _write(self, name: str, text: str) -> Path:
        p = self.tmp / name
        p.write_text(text)
        return p

    def _router_yaml(self, host: str, listen: list[str], connect: list[str], pool: dict | None = None) -> Path:
        body: dict[str, Any] = {"host": host, "listen": listen, "connect": connect, "lease_ms": self.opts.lease_ms}
        if pool is not None:
            body["pool"] = pool
        return self._write(f"router-{host}.yaml", json.dumps(body, indent=1))  # JSON is YAML

    def _build(self) -> None:
        o, pl = self.opts, self.plant
        compute, plant = pl.add_host("compute"), pl.add_host("plant")
        for c in o.cell_ids:
            pl.add_host(c)
            pl.link(c, "compute")
            pl.link(c, "plant")
        self.plans_dir = self.tmp / "plans"
        self.jobs_dir = self.tmp / "pool-jobs"
        pool = {"cells": o.cell_ids, "jobs_dir": str(self.jobs_dir)}
        self.compute_yaml = self._router_yaml(
            "compute",
            [_ep("127.0.0.1", ROUTER_PORT)] + [_ep(compute.address_to(c), ROUTER_PORT) for c in o.cell_ids],
            [],
            pool,
        )
        self.start_router("compute")
        plant_yaml = self._router_yaml(
            "plant", [_ep("127.0.0.1", ROUTER_PORT)] + [_ep(plant.address_to(c), ROUTER_PORT) for c in o.cell_ids], []
        )
        self.procs["plant/router"] = plant.spawn([*_PY, "-v", "router", str(plant_yaml)], "router")
        self.relay_controls: dict[str, Path] = {}
        for c in o.cell_ids:
            up = compute.address_to(c)
            port = ROUTER_PORT
            if c in o.relayed:
                port = RELAY_PORT
                ctl = self._write(f"relay-{c}.json", json.dumps({"delay_ms": 0.0, "loss": 0.0}))
                spec = self._write(
                    f"relay-{c}-spec.json",
                    json.dumps({"listen": [up, RELAY_PORT], "target": ["127.0.0.1", ROUTER_PORT], "control": str(ctl)}),
                )
                self.relay_controls[c] = ctl
                code = "import sys; from cellctl.bench.reliability.relay import main; main(sys.argv[1])"
                self.procs[f"compute/relay-{c}"] = compute.spawn([sys.executable, "-c", code, str(spec)], f"relay-{c}")
            y = self._router_yaml(
                c,
                [_ep("127.0.0.1", HOST_ROUTER_PORT)],
                [_ep("127.0.0.1", ROUTER_PORT), _ep(up, port), _ep(pl.hosts["plant"].address_to(c), ROUTER_PORT)],
            )
            self.procs[f"{c}/router"] = pl.hosts[c].spawn([*_PY, "-v", "router", str(y)], "router")
        for i in range(o.workers):
            self.start_worker(i)
        for i, c in enumerate(o.cell_ids):
            self.start_cell(c, o.bin_types[i] if i < len(o.bin_types) else "case_study")
        for c in o.cell_ids:
            self.agents[c] = self._agent(c)

    def bus_set(self, port: int = ROUTER_PORT) -> list[str]:
        ep = json.dumps([_ep("127.0.0.1", port)])
        return [
            "--set",
            f"bus.listen={ep}",
            "--set",
            f"bus.connect={ep}",
            "--set",
            f"bus.lease_ms={self.opts.lease_ms}",
        ]

    def start_router(self, host: str) -> None:
        yaml_path = self.compute_yaml if host == "compute" else self.tmp / f"router-{host}.yaml"
        self.procs[f"{host}/router"] = self.plant.hosts[host].spawn([*_PY, "-v", "router", str(yaml_path)], "router")
        if not self.plant.wait_log(host, "router", "planner pool for" if host == "compute" else "listening", 60):
            raise CellError(f"router of {host} did not start: {self.plant.log_of(host, 'router')[-2000:]}")

    def start_worker(self, i: int) -> None:
        args = [*_PY, "-v", "worker", "planner", "--backend", "pool", *self.bus_set()]
        args += ["--set", f"planner.plans_dir={self.plans_dir}"]
        self.procs[f"compute/planner{i}"] = self.plant.hosts["compute"].spawn(args, f"planner{i}")

    def start_cell(self, c: str, bin_type: str) -> None:
        out = self.tmp / c
        sets = [
            f"cell.id={c}",
            f"recording.dir={out}",
            f"recording.index={out}/cells.db",
            f"planner.plans_dir={out}/plans-unused",
            "supervisor.spawn_workers=[robot, camera, classifier]",
            "supervisor.required_workers=[robot, camera, classifier, planner]",
            "supervisor.status_period_s=0.5",
            f"sim.bin_type={bin_type}",
            *FAST_SIM,
            *self.opts.cell_overrides,
        ]
        args = [*_PY, "-v", "run", "--with-workers", *self.bus_set()]
        for s in sets:
            args += ["--set", s]
        self.procs[f"{c}/daemon"] = self.plant.hosts[c].spawn(args, "daemon")

    def _agent(self, c: str) -> PlcAgent:
        code = "from cellctl.bench.reliability.cluster import plc_agent_main; plc_agent_main()"
        argv = ["ip", "netns", "exec", self.plant.hosts["plant"].ns, sys.executable, "-c", code]
        log = (self.tmp / f"plant-plc-{c}.log").open("ab")
        proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, start_new_session=True)
        log.close()
        self.plant.procs.append((f"plant/plc-{c}", proc))
        agent = PlcAgent(proc, c)
        agent.call("open", cell=c, connect=[_ep("127.0.0.1", ROUTER_PORT)], lease_ms=self.opts.lease_ms)
        return agent

    # --- faults -------------------------------------------------------------------------

    def host(self, name: str) -> Host:
        return self.plant.hosts[name]

    def shape(self, cell: str, **shape: float) -> None:
        """Set the relay of ``cell``'s compute link (delay_ms, jitter_ms, loss, rto_ms, seed)."""
        ctl = self.relay_controls.get(cell)
        if ctl is None:
            raise CellError(f"{cell}'s compute link has no relay; relayed cells: {sorted(self.relay_controls)}")
        tmp = ctl.with_suffix(".tmp")
        tmp.write_text(json.dumps(shape))
        tmp.replace(ctl)

    def kill_router(self, host: str) -> None:
        proc = self.procs.pop(f"{host}/router")
        Plant.stop(proc, signal.SIGKILL)

    def index_rows(self, cell: str) -> list[dict[str, Any]]:
        import sqlite3

        db = self.tmp / cell / "cells.db"
        if not db.exists():
            return []
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
        try:
            cur = con.execute("SELECT cycle_id, outcome, reason, log_path FROM cycles ORDER BY seq")
            return [dict(zip(("cycle_id", "outcome", "reason", "log_path"), r, strict=True)) for r in cur]
        finally:
            con.close()


# --- the PLC agent (runs in the plant host) ---------------------------------------------


def plc_agent_main() -> None:
    """JSON-lines PLC agent: one command per stdin line, one answer per stdout line."""
    import logging

    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    state: dict[str, Any] = {"plc": None, "log": [], "results": []}
    for line in sys.stdin:
        try:
            req = json.loads(line)
            out = _agent_op(state, req.pop("op"), req)
            sys.stdout.write(json.dumps({"ok": out}) + "\n")
        except Exception as err:  # every failure goes back to the driver, named
            sys.stdout.write(json.dumps({"error": f"{type(err).__name__}: {err}"}) + "\n")
        sys.stdout.flush()
    if state["plc"] is not None:
        state["plc"].close()


def _agent_op(state: dict[str, Any], op: str, a: dict[str, Any]) -> Any:
    from cellctl.bus import keys
    from cellctl.bus.codec import decode, decode_as, encode
    from cellctl.bus.plc_client import PlcClient
    from cellctl.config import load_config
    from cellctl.messages import Command, PlanJobQuery, PlanJobRequest, PoolStatsRequest, PoseMsg, Status

    if op == "open":
        ep = json.dumps(a["connect"])
        cfg = load_config(None, [f"cell.id={a['cell']}", f"bus.connect={ep}", f"bus.lease_ms={a['lease_ms']}"])
        plc = PlcClient(cfg, f"plc-{a['cell']}")
        log = state["log"]

        def on_status(sample: Any) -> None:
            st = decode_as(Status, sample.payload.to_bytes())
            log.append([time.time(), st.state, st.step, bool(st.workers.get("planner")), st.last_error])

        def on_result(sample: Any) -> None:
            r = decode(sample.payload.to_bytes())
            state["results"].append([time.time(), r.cycle_id, r.outcome.value, r.reason])

        state["subs"] = [
            plc.session.declare_subscriber(keys.status(plc.cell), on_status),
            plc.session.declare_subscriber(keys.result(plc.cell), on_result),
        ]
        state["plc"] = plc
        return True
    plc: PlcClient = state["plc"]
    if op == "wait_workers":  # on a fresh Status: the last one may predate a fault
        plc.last_status = None
        plc.drain()
        return plc.wait_workers(a["roles"], a.get("timeout", 120))
    if op == "to_idle":
        plc.last_status = None
        plc.to_idle(a.get("timeout", 30))
        return True
    if op == "start":  # start a cycle and return at once (faults are injected meanwhile)
        plc.drain()
        ack = plc.command("start")
        return {"accepted": ack.accepted, "reason": ack.reason, "t": time.time()}
    if op == "cycle":
        t0 = time.time()
        res = plc.run_cycle(a.get("timeout", 300))
        return {
            "cycle_id": res.cycle_id,
            "outcome": res.outcome.value,
            "reason": res.reason,
            "planner_job_id": res.planner_job_id,
            "plan_id": res.plan_id,
            "t0": t0,
            "t1": time.time(),
        }
    if op == "wait_state":
        st = plc.wait_for(lambda s: s.state in a["states"], a.get("timeout", 60))
        return None if st is None else {"state": st.state, "t": time.time(), "last_error": st.last_error}
    if op == "cmd":
        ack = plc.command(a["name"], timeout=a.get("timeout", 10))
        return {"accepted": ack.accepted, "reason": ack.reason}
    if op == "status":
        st = plc.status(a.get("timeout", 5))
        return {"state": st.state, "workers": st.workers, "last_error": st.last_error}
    if op == "log":
        return [e for e in state["log"] if e[0] >= a.get("since", 0.0)]
    if op == "results":
        return state["results"]
    if op == "ack_rtt":  # cmd→ack by query: a command refused in this state changes nothing
        out = []
        for i in range(a.get("n", 50)):
            cmd = Command(command=a.get("command", "unhold"), request_id=f"rtt-{i}")
            t = time.perf_counter()
            try:
                plc.send(cmd, timeout=5)
            except CellError:  # no daemon or no answer: this sample is left out, as before
                continue
            out.append((time.perf_counter() - t) * 1000.0)
        return out
    if op == "submit":
        req = PlanJobRequest(
            bin_type=a.get("bin_type", "case_study"),
            bin_pose=PoseMsg.model_validate(a["pose"]) if "pose" in a else PoseMsg.from_matrix(_eye(a.get("x", 1.0))),
        )
        t = time.time()
        (r,) = list(plc.session.get(keys.planner_jobs(plc.cell), payload=encode(req), timeout=10))
        return {"job_id": decode(r.ok.payload.to_bytes()).job_id, "t": t}
    if op == "job":
        (r,) = list(
            plc.session.get(keys.planner_jobs(plc.cell), payload=encode(PlanJobQuery(job_id=a["job_id"])), timeout=10)
        )
        rep = decode(r.ok.payload.to_bytes())
        return {"state": rep.state, "plan_id": rep.plan_id, "reason": rep.reason, "t": time.time()}
    if op == "lookup":
        from cellctl.messages import PlanLookupReply, PlanLookupRequest

        req = PlanLookupRequest(bin_type=a.get("bin_type", "case_study"), bin_pose=PoseMsg.model_validate(a["pose"]))
        (r,) = list(plc.session.get(keys.worker_op(plc.cell, "planner", "lookup"), payload=encode(req), timeout=30))
        rep = decode_as(PlanLookupReply, r.ok.payload.to_bytes())
        return {"hit": rep.hit, "plan_id": rep.plan_id, "reason": rep.reason}
    if op == "pool_stats":
        (r,) = list(plc.session.get(keys.pool_stats(), payload=encode(PoolStatsRequest()), timeout=10))
        return decode(r.ok.payload.to_bytes()).model_dump(mode="json")
    raise CellError(f"PLC agent op {op!r} is unknown")


def _eye(x: float) -> Any:
    import numpy as np

    T = np.eye(4)
    T[0, 3] = x
    return T


# --- scenarios shared by the tests and the bench -----------------------------------------


def bring_up(cl: Cluster, timeout: float = 300.0) -> None:
    """Wait until every cell sees all its workers (the pool's planner included) and is Idle."""
    for c, agent in cl.agents.items():
        if not agent.call("wait_workers", timeout=timeout, roles=["robot", "camera", "classifier", "planner"]):
            raise CellError(f"{c}: workers not all alive within {timeout:g} s: {agent.call('status')}")
        agent.call("to_idle", timeout=60)


def first_cycles(cl: Cluster, timeout: float = 600.0) -> list[dict[str, Any]]:
    """Each cell's first cycle, one after the other: a replan where no plan fits, a hit where one does."""
    out = []
    for c, agent in cl.agents.items():
        r = agent.call("cycle", timeout=timeout)
        r["cell"] = c
        if r["outcome"] == "replan_required" and r["planner_job_id"]:
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                st = agent.call("job", job_id=r["planner_job_id"])
                if st["state"] in ("done", "failed"):
                    r["job"] = st
                    break
                time.sleep(1.0)
        agent.call("to_idle", timeout=60)
        out.append(r)
    return out


def link_fault(
    cl: Cluster, case: str, cell: str, lease_s: float, timeout: float = 300.0, other: str | None = None
) -> dict[str, Any]:
    """Inject one fault mid-cycle on ``cell``; detection time, safe state, recovery by Clear/Reset/Start.

    Cases: ``link_down`` (the cell↔compute veth down for 2 leases; the router mesh may route
    around it through the plant host and another cell host), ``isolate`` (both of the cell's
    links down for 2 leases + 1 s: no path to the pool; the PLC sees nothing meanwhile, so the
    times come from the cell's own index row), ``router_restart`` (the
    compute router killed and restarted), ``latency_loss`` (the relay at 80 ms ± 20 and 10 %
    loss for one cycle; expected: no fault). ``other``: a cell that submits a planning job
    while the fault lasts; whether the pool took it (``other_job``) shows it kept serving.
    """
    agent = cl.agents[cell]
    agent.call("to_idle", timeout=60)
    if case == "latency_loss":
        cl.shape(cell, delay_ms=80.0, jitter_ms=20.0, loss=0.1, seed=0)
        try:
            r = agent.call("cycle", timeout=timeout)
        finally:
            cl.shape(cell, delay_ms=0.0, loss=0.0)
        return {
            "case": case,
            "cell": cell,
            "shape": "80 ± 20 ms, 10 % chunks held 200 ms",
            "detection_s": None,
            "safe_state": None,
            "cycle_outcome": r["outcome"],
            "cycle_s": round(r["t1"] - r["t0"], 2),
            "recovered": r["outcome"] in ("completed", "replan_required"),
        }
    start = agent.call("start")
    if not start["accepted"]:
        raise CellError(f"{cell}: start refused: {start['reason']}")
    agent.call("wait_state", states=["Execute"], timeout=30)
    time.sleep(1.0)  # mid-cycle: approaching/identifying/scanning
    t_fault = time.time()
    if case == "link_down":
        link = cl.plant.link_between(cell, "compute")
        link.down()
    elif case == "isolate":
        links = [cl.plant.link_between(cell, h) for h in ("compute", "plant")]
        for ln in links:
            ln.down()
        time.sleep(2 * lease_s + 1.0)
        for ln in links:
            ln.up()
        return _isolate_outcome(cl, agent, cell, t_fault, timeout)
    elif case == "router_restart":
        cl.kill_router("compute")
    else:
        raise ConfigError(
            f"link fault case {case!r} is unknown; expected link_down, isolate, router_restart, latency_loss"
        )
    # Complete: the cycle did not notice (the router mesh routed around a cut link)
    safe = agent.call("wait_state", states=["Aborted", "Held", "Stopped", "Complete"], timeout=lease_s + 120)
    log = agent.call("log", since=t_fault)
    lost = next((e[0] for e in log if not e[3]), None)
    other_job = None
    if other is not None and case == "link_down":
        job = cl.agents[other].call("submit", bin_type="case_study", x=2.0 + len(log) * 1e-3)
        deadline = time.monotonic() + 2 * lease_s + 10
        while time.monotonic() < deadline:
            other_job = cl.agents[other].call("job", job_id=job["job_id"])
            if other_job["state"] != "queued":
                break
            time.sleep(0.2)
        other_job = {
            "cell": other,
            "state": other_job["state"] if other_job else None,
            "claimed_s": round(other_job["t"] - job["t"], 3) if other_job else None,
        }
    if case == "link_down":
        time.sleep(max(0.0, 2 * lease_s - (time.time() - t_fault)))
        link.up()
    else:
        cl.start_router("compute")
    t_back = time.time()
    ok = agent.call("wait_workers", roles=["planner"], timeout=60)
    t_seen = time.time()
    rec = None
    if ok:
        agent.call("to_idle", timeout=60)
        rec = agent.call("cycle", timeout=timeout)
    return {
        "case": case,
        "cell": cell,
        "detection_s": None if safe is None or safe["state"] == "Complete" else round(safe["t"] - t_fault, 3),
        "planner_lost_s": None if lost is None else round(lost - t_fault, 3),
        "safe_state": None if safe is None else safe["state"],
        "reason": None if safe is None else safe["last_error"],
        "planner_back_s": round(t_seen - t_back, 3) if ok else None,
        "recovered": bool(rec and rec["outcome"] in ("completed", "replan_required")),
        "recovery_cycle": None if rec is None else rec["outcome"],
        "other_cell_job": other_job,
    }


def _iso_to_epoch(stamp: str | None) -> float | None:
    import datetime as dt

    return None if stamp is None else dt.datetime.fromisoformat(stamp).timestamp()


def _isolate_outcome(cl: Cluster, agent: PlcAgent, cell: str, t_fault: float, timeout: float) -> dict[str, Any]:
    """After an isolation: when the cell's own record says the cycle ended, and how, then recover."""
    import sqlite3

    t_back = time.time()
    ok = agent.call("wait_workers", roles=["planner"], timeout=60)
    t_seen = time.time()
    st = agent.call("status", timeout=10)
    con = sqlite3.connect(f"file:{cl.tmp / cell / 'cells.db'}?mode=ro", uri=True)
    try:
        finished, outcome, reason = con.execute(
            "SELECT finished, outcome, reason FROM cycles ORDER BY seq DESC LIMIT 1"
        ).fetchone()
    finally:
        con.close()
    t_end = _iso_to_epoch(finished)
    rec = None
    if ok:
        agent.call("to_idle", timeout=60)
        rec = agent.call("cycle", timeout=timeout)
    return {
        "case": "isolate",
        "cell": cell,
        "detection_s": None if t_end is None else round(t_end - t_fault, 3),
        "detection_from": "the cell's index row (finished) against the cut",
        "safe_state": st["state"],
        "record_outcome": outcome,
        "reason": reason,
        "planner_back_s": round(t_seen - t_back, 3) if ok else None,
        "recovered": bool(rec and rec["outcome"] in ("completed", "replan_required")),
        "recovery_cycle": None if rec is None else rec["outcome"],
    }


def records_check(cl: Cluster) -> dict[str, Any]:
    """Per cell: index rows, duplicates, cycles the PLC saw that are not recorded, rows not finished."""
    out = {}
    for c, agent in cl.agents.items():
        rows = cl.index_rows(c)
        ids = [r["cycle_id"] for r in rows]
        seen = {r[1] for r in agent.call("results")}
        out[c] = {
            "rows": len(rows),
            "recorded_twice": len(ids) - len(set(ids)),
            "seen_not_recorded": sorted(seen - set(ids)),
            "unfinished": [r["cycle_id"] for r in rows if r["outcome"] is None],
            "logs_missing": [r["cycle_id"] for r in rows if not Path(r["log_path"]).exists()],
            "outcomes": {o: sum(r["outcome"] == o for r in rows) for o in {r["outcome"] for r in rows}},
        }
    return out


def _pct(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    s = sorted(xs)
    return round(s[min(len(s) - 1, int(round(q / 100.0 * (len(s) - 1))))], 2)


def burst(cl: Cluster, per_cell: int, timeout: float = 900.0) -> dict[str, Any]:
    """``per_cell`` replan requests from every cell at once; latency submit→done (0.5 s polling).

    Every request is the same work (case-study bin, same pose): the pool does not merge equal
    requests, so the latencies compare worker counts and nothing else.
    """
    subs = []
    for _ in range(per_cell):
        for c, agent in cl.agents.items():
            subs.append((c, agent, agent.call("submit", bin_type="case_study", x=1.0)))
    lat, states = [], {}
    deadline = time.monotonic() + timeout
    pending = list(subs)
    while pending and time.monotonic() < deadline:
        nxt = []
        for c, agent, s in pending:
            st = agent.call("job", job_id=s["job_id"])
            if st["state"] in ("done", "failed"):
                lat.append(st["t"] - s["t"])
                states[s["job_id"]] = st["state"]
            else:
                nxt.append((c, agent, s))
        pending = nxt
        time.sleep(0.5)
    return {
        "submitted": len(subs),
        "done": sum(v == "done" for v in states.values()),
        "failed": sum(v == "failed" for v in states.values()),
        "unfinished": len(pending),
        "latency_s": {
            "p50": _pct(lat, 50),
            "max": _pct(lat, 100),
            "mean": round(sum(lat) / len(lat), 2) if lat else None,
        },
        "makespan_s": round(max(lat), 2) if lat else None,
    }


def bench_cluster(opts: BenchOptions) -> dict[str, Any]:
    """``cellctl bench cluster``: 3 cells, a 2-worker pool, a PLC host; cycles, jobs, faults, latencies.

    ``--n`` is the replan requests per cell in each burst (default 3). Bounded: every wait has
    a timeout; the burst with 1 worker and with 2 runs on the same plant (a worker is stopped
    for the first), side by side.
    """
    per_cell = opts.n or 3
    tmp = Path(tempfile.mkdtemp(prefix="cellctl-cluster-"))
    o = ClusterOptions(
        cells=3,
        workers=2,
        relayed=("cell2",),
        cell_overrides=tuple(opts.overrides),
        bin_types=("case_study", "case_study", "tote"),
    )
    lease_s = o.lease_ms / 1000.0
    t_all = time.monotonic()
    with Cluster(o, tmp) as cl:
        print("cluster: bringing up 3 cells, 2 pool workers, PLC host …", file=sys.stderr)
        bring_up(cl)
        first = first_cycles(cl)
        print(f"cluster: first cycles {[(r['cell'], r['outcome']) for r in first]}", file=sys.stderr)
        rtt = cl.agents["cell1"].call("ack_rtt", n=200, timeout=120)
        # burst with 2 workers, then with 1 (worker 1 stopped) on the same plant
        b2 = burst(cl, per_cell)
        print(f"cluster: burst, 2 workers: {json.dumps(b2)}", file=sys.stderr)
        Plant.stop(cl.procs.pop("compute/planner1"))
        time.sleep(lease_s + 1)
        b1 = burst(cl, per_cell)
        print(f"cluster: burst, 1 worker: {json.dumps(b1)}", file=sys.stderr)
        cl.start_worker(1)
        deadline = time.monotonic() + 120
        while len(cl.agents["cell1"].call("pool_stats")["workers"]) < 2 and time.monotonic() < deadline:
            time.sleep(0.5)
        faults = []
        for case, cell in (
            ("link_down", "cell1"),
            ("isolate", "cell1"),
            ("latency_loss", "cell2"),
            ("router_restart", "cell3"),
        ):
            print(f"cluster: fault {case} on {cell} …", file=sys.stderr)
            faults.append(link_fault(cl, case, cell, lease_s, other="cell3" if case == "link_down" else None))
            print(f"cluster: {json.dumps(faults[-1])}", file=sys.stderr)
        more = {}
        for c, agent in cl.agents.items():  # one more cycle each: every cell still works
            agent.call("to_idle", timeout=60)
            more[c] = agent.call("cycle", timeout=300)["outcome"]
        stats = cl.agents["cell1"].call("pool_stats")
        records = records_check(cl)
        cells = []
        for c in o.cell_ids:
            rows = cl.index_rows(c)
            cells.append(
                {
                    "cell": c,
                    "cycles_completed": sum(r["outcome"] == "completed" for r in rows),
                    "cycles_recorded": len(rows),
                    "first_cycle": next(r["outcome"] for r in first if r["cell"] == c),
                    "last_cycle": more[c],
                    "records": records[c],
                }
            )
    return {
        "topology": {
            "hosts": ["compute", "plant", *o.cell_ids],
            "links": "veth, 169.254.0.0/16",
            "routers": "one per host",
            "relayed_link": "cell2<->compute",
            "lease_ms": o.lease_ms,
        },
        "cells": cells,
        "plans_shared": {
            r["cell"]: {
                "first_cycle": r["outcome"],
                "plan_id": r.get("plan_id"),
                "job_plan_id": r.get("job", {}).get("plan_id"),
            }
            for r in first
        },
        "jobs": {
            "submitted": stats["submitted"],
            "planned": stats["planned"],
            "failed": stats["failed"],
            "requeued": stats["requeued"],
            "planned_twice": stats["planned_twice"],
            "per_worker": stats["per_worker"],
        },
        "burst": {
            "requests_per_cell": per_cell,
            "workers_2": b2,
            "workers_1": b1,
            "makespan_ratio_1_over_2": round(b1["makespan_s"] / b2["makespan_s"], 2)
            if b1["makespan_s"] and b2["makespan_s"]
            else None,
        },
        "cmd_ack_ms": {
            "path": "plant host -> plant router -> cell host router -> daemon",
            "n": len(rtt),
            "p50": _pct(rtt, 50),
            "p99": _pct(rtt, 99),
        },
        "link_faults": faults,
        "bound_s": lease_s + 1.0,
        "wall_s": round(time.monotonic() - t_all, 1),
        "seed": opts.seed,
    }
