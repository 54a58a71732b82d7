"""The planner pool on loopback: real `cellctl router` with the job queue, real pool workers.

Each job goes to exactly one worker; a worker killed mid-job loses its claim with its
liveliness (re-queued, then failed visibly after ``max_attempts``); a plan made for one
cell is found by another cell at the same station pose and robot model, and not otherwise.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import decode, decode_as, encode
from cellctl.messages import (
    PlanJobQuery,
    PlanJobReply,
    PlanJobRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PoolStats,
    PoolStatsRequest,
    PoseMsg,
)
from cellctl.planning.planfile import read_document
from tests.conftest import free_port

LEASE_MS = 1000


class Pool:
    """A compute host on loopback: the router with the queue and N pool workers."""

    def __init__(self, tmp: Path, workers: int, max_attempts: int = 2) -> None:
        self.tmp, self.port = tmp, free_port()
        self.ep = f"tcp/127.0.0.1:{self.port}"
        self.jobs_dir, self.plans = tmp / "jobs", tmp / "plans"
        self.yaml = tmp / "compute.yaml"
        self.yaml.write_text(
            json.dumps(
                {
                    "host": "compute",
                    "listen": [self.ep],
                    "lease_ms": LEASE_MS,
                    "pool": {"cells": ["cell1", "cell2"], "jobs_dir": str(self.jobs_dir), "max_attempts": max_attempts},
                }
            )
        )
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._spawn("router", ["router", str(self.yaml)])
        # a worker whose first connect finds no listener exits (as under systemd, which restarts it);
        # the router process takes seconds to import on a loaded machine, so wait for its socket
        self._wait_listening(timeout=60)
        for i in range(workers):
            self.start_worker(i)
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([self.ep]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = self._open(conf)

    def _wait_listening(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return
            except OSError:
                time.sleep(0.2)
        raise AssertionError(f"router not listening on {self.ep} within {timeout} s: {self.logs()}")

    def _open(self, conf: zenoh.Config) -> zenoh.Session:
        deadline = time.monotonic() + 30
        while True:
            try:
                return zenoh.open(conf)
            except Exception:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)

    def _spawn(self, name: str, args: list[str]) -> None:
        log = (self.tmp / f"{name}.log").open("ab")
        self.procs[name] = subprocess.Popen(
            [sys.executable, "-m", "cellctl", "-v", *args], stdout=log, stderr=subprocess.STDOUT, start_new_session=True
        )
        log.close()

    def restart_router(self) -> None:
        """SIGKILL the router (queue and all) and start it again on the same files."""
        p = self.procs.pop("router")
        os.killpg(p.pid, signal.SIGKILL)
        p.wait(timeout=10)
        self._spawn("router", ["router", str(self.yaml)])

    def start_worker(self, i: int) -> None:
        sets = [f'bus.connect=["{self.ep}"]', f"bus.lease_ms={LEASE_MS}", f"planner.plans_dir={self.plans}"]
        self._spawn(f"w{i}", ["worker", "planner", "--backend", "pool", *[x for s in sets for x in ("--set", s)]])

    def get(self, key: str, msg: object, timeout: float = 10.0) -> bytes:
        replies = list(self.session.get(key, payload=encode(msg), timeout=timeout))
        assert replies and replies[0].ok is not None, f"no reply on {key}"
        return replies[0].ok.payload.to_bytes()

    def stats(self) -> PoolStats:
        return decode_as(PoolStats, self.get(keys.pool_stats(), PoolStatsRequest()))

    def wait_workers(self, n: int, timeout: float = 120.0) -> list[str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                w = self.stats().workers
            except AssertionError:
                w = []
            if len(w) >= n:
                return w
            time.sleep(0.3)
        raise AssertionError(f"{n} pool workers not up within {timeout} s: {self.logs()}")

    def submit(self, cell: str, x: float, bin_type: str = "tote") -> str:
        req = PlanJobRequest(bin_type=bin_type, bin_pose=PoseMsg.from_matrix(_pose(x)))
        return decode_as(PlanJobReply, self.get(keys.planner_jobs(cell), req)).job_id

    def job(self, cell: str, job_id: str) -> PlanJobReply:
        return decode_as(PlanJobReply, self.get(keys.planner_jobs(cell), PlanJobQuery(job_id=job_id)))

    def record(self, job_id: str) -> dict:
        return read_document(self.jobs_dir / f"{job_id}.json")

    def wait_job(self, cell: str, job_id: str, states: tuple[str, ...], timeout: float) -> PlanJobReply:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            r = self.job(cell, job_id)
            if r.state in states:
                return r
            time.sleep(0.1)
        raise AssertionError(f"job {job_id} not in {states} within {timeout} s: {self.job(cell, job_id)}")

    def logs(self) -> str:
        return "\n".join(f"--- {p.name}\n{p.read_text()[-1500:]}" for p in sorted(self.tmp.glob("*.log")))

    def close(self) -> None:
        self.session.close()
        for p in self.procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in self.procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=5)


def _pose(x: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = x
    return T


def _pid(instance: str) -> int:
    return int(instance[1:].split("-", 1)[0])  # pool worker instances are p<pid>-<hex>


@pytest.fixture
def pool2(tmp_path: Path):
    p = Pool(tmp_path, workers=2)
    try:
        yield p
    finally:
        p.close()


def test_claims_are_leases_a_killed_claimant_requeues_then_fails_visibly(pool2: Pool) -> None:
    """Kill the claimant mid-job: re-queued within lease + 1 s and claimed by the other; kill that one too: failed."""
    pool2.wait_workers(2)
    job = pool2.submit("cell1", 1.0)
    pool2.wait_job("cell1", job, ("running",), 30)
    first = pool2.record(job)["claimant"]
    t = time.monotonic()
    os.kill(_pid(first), signal.SIGKILL)
    deadline = t + LEASE_MS / 1000 + 1.0
    while time.monotonic() < deadline + 5:
        rec = pool2.record(job)
        if rec["state"] == "running" and rec["claimant"] != first:
            break
        time.sleep(0.05)
    requeued_after = time.monotonic() - t
    assert rec["claimant"] not in (None, first), rec
    assert rec["attempt"] == 2
    assert requeued_after <= LEASE_MS / 1000 + 1.0 + 0.5, f"re-claimed {requeued_after:.2f} s after the kill"
    assert pool2.stats().requeued == 1
    t = time.monotonic()
    os.kill(_pid(rec["claimant"]), signal.SIGKILL)
    end = pool2.wait_job("cell1", job, ("failed", "done"), LEASE_MS / 1000 + 3.0)
    assert end.state == "failed"
    assert "lost mid-job (attempt 2 of 2)" in end.reason
    assert time.monotonic() - t <= LEASE_MS / 1000 + 1.5
    # the cells see no planner once the pool has no worker
    assert not [r for r in pool2.session.liveliness().get(keys.alive_all("cell1"), timeout=2) if r.ok is not None]


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_each_job_planned_exactly_once_by_two_workers(pool2: Pool) -> None:
    """Three jobs from two cells, two workers: each planned once, both workers used, records agree."""
    pool2.wait_workers(2)
    jobs = [
        ("cell1", pool2.submit("cell1", 1.0)),
        ("cell2", pool2.submit("cell2", 1.3)),
        ("cell1", pool2.submit("cell1", 1.6)),
    ]
    for cell, j in jobs:
        assert pool2.wait_job(cell, j, ("done", "failed"), 400).state == "done"
    st = pool2.stats()
    assert (st.submitted, st.planned, st.planned_twice, st.requeued) == (3, 3, 0, 0)
    assert sum(st.per_worker.values()) == 3 and len(st.per_worker) == 2
    assert all(len(pool2.record(j)["planned_by"]) == 1 for _, j in jobs)
    # another cell's job id is not this cell's
    assert pool2.job("cell2", jobs[0][1]).state == "failed"


def test_a_restarted_queue_keeps_its_jobs(tmp_path: Path) -> None:
    """Queued jobs survive a SIGKILL of the compute router: the records in jobs_dir are the queue."""
    pool = Pool(tmp_path, workers=0)
    try:
        deadline = time.monotonic() + 30
        while True:  # the queue's queryables come up a moment after the router
            try:
                job = pool.submit("cell2", 1.0)
                break
            except AssertionError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)
        pool.restart_router()
        deadline = time.monotonic() + 30
        while True:
            try:
                st = pool.job("cell2", job)
                break
            except AssertionError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.3)
        assert st.state == "queued", st
        assert pool.stats().submitted == 1
        # no worker: the cells see no planner (the pool's token is only there while a worker lives)
        assert not [r for r in pool.session.liveliness().get(keys.alive_all("cell2"), timeout=2) if r.ok is not None]
    finally:
        pool.close()


def test_unknown_cell_is_refused_by_name(pool2: Pool) -> None:
    pool2.wait_workers(1)
    req = PlanJobRequest(bin_type="tote", bin_pose=PoseMsg.from_matrix(_pose(1.0)))
    replies = list(pool2.session.get(keys.planner_jobs("cell9"), payload=encode(req), timeout=5))
    assert replies and replies[0].err is not None
    assert "cell 'cell9' is not served by this planner pool" in decode(replies[0].err.payload.to_bytes()).reason


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_plans_shared_across_cells_same_station_and_robot_only(tmp_path: Path) -> None:
    """cell1's plan is found by cell2 at the same pose; not at another pose, not for another robot model."""
    from cellctl.planning.planfile import list_plans, plan_path, write_plan

    pool = Pool(tmp_path, workers=1)
    try:
        pool.wait_workers(1)
        job = pool.submit("cell1", 1.0)
        done = pool.wait_job("cell1", job, ("done", "failed"), 400)
        assert done.state == "done", done

        def lookup(cell: str, x: float) -> PlanLookupReply:
            req = PlanLookupRequest(bin_type="tote", bin_pose=PoseMsg.from_matrix(_pose(x)))
            return decode_as(PlanLookupReply, pool.get(keys.worker_op(cell, "planner", "lookup"), req, timeout=30))

        hit = lookup("cell2", 1.01)
        assert hit.hit and hit.plan_id == done.plan_id, hit.reason
        miss = lookup("cell2", 1.5)
        assert not miss.hit and "differs from plan" in miss.reason
        # the same plan for another robot model: a miss that says so
        (plan,), _ = list_plans(pool.plans, "tote", "external")
        other = dataclasses.replace(plan, robot_model_id="another-arm")
        plan_path(pool.plans, plan).unlink()
        write_plan(other, plan_path(pool.plans, other))
        again = lookup("cell2", 1.0)
        assert not again.hit and "robot model" in again.reason
    finally:
        pool.close()


@pytest.mark.slow
@pytest.mark.timeout(1500)
def test_a_frozen_claimant_loses_its_lease_and_a_late_second_result_is_counted_not_recorded(pool2: Pool) -> None:
    """SIGSTOP the claimant: re-claimed by the other within lease + 1 s; both finish: one job, planned_twice 1."""
    pool2.wait_workers(2)
    job = pool2.submit("cell1", 1.0)
    pool2.wait_job("cell1", job, ("running",), 30)
    frozen = pool2.record(job)["claimant"]
    t = time.monotonic()
    os.kill(_pid(frozen), signal.SIGSTOP)
    try:
        while time.monotonic() < t + LEASE_MS / 1000 + 6:
            rec = pool2.record(job)
            if rec["claimant"] not in (None, frozen):
                break
            time.sleep(0.05)
        assert rec["claimant"] not in (None, frozen), rec
        assert time.monotonic() - t <= LEASE_MS / 1000 + 1.5
    finally:
        os.kill(_pid(frozen), signal.SIGCONT)
    assert pool2.wait_job("cell1", job, ("done", "failed"), 600).state == "done"
    deadline = time.monotonic() + 600
    while pool2.stats().planned_twice == 0 and time.monotonic() < deadline:
        time.sleep(0.5)
    st = pool2.stats()
    assert (st.submitted, st.planned, st.planned_twice, st.requeued) == (1, 1, 1, 1)
    assert sorted(pool2.record(job)["planned_by"]) == sorted(st.workers)
