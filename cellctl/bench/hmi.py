"""``cellctl bench hmi``: how fast the HMI answers ``GET /api/status`` while sim cycles run.

The sim cell runs as in production (daemon here, workers as child processes), the HMI in its
own ``cellctl hmi`` process, and a browser-like client in a third process: one server-sent-events
stream open (as a page is) and ``GET /api/status`` on a keep-alive connection at a fixed rate.
Reported: p50/p95/p99/max in ms over the requests made while a cycle ran.
"""

from __future__ import annotations

import http.client
import multiprocessing
import socket
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.errors import CellError

__all__ = ["bench_hmi"]

RATE_HZ = 50.0
TARGET_P99_MS = 50.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def _sse_reader(port: int, stop: threading.Event, counts: dict[str, int]) -> None:
    """Hold one event stream open, as a page does, and count the updates."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        sock.sendall(b"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept: text/event-stream\r\n\r\n")
        sock.settimeout(0.5)  # wake up to look at `stop`
        while not stop.is_set():
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                continue
            if not chunk:
                return
            counts["sse_events"] = counts.get("sse_events", 0) + chunk.count(b"event: ")


def _client(port: int, rate_hz: float, stop: Any, out: Any) -> None:
    """The measuring client (a process of its own): one event stream open, GET /api/status at ``rate_hz``."""
    counts: dict[str, int] = {}
    stop_sse = threading.Event()
    sse = threading.Thread(target=_sse_reader, args=(port, stop_sse, counts), daemon=True)
    sse.start()
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    samples: list[tuple[float, float]] = []
    errors: list[str] = []
    period = 1.0 / rate_hz
    next_t = time.perf_counter()
    while not stop.is_set():
        next_t += period
        t0 = time.perf_counter()
        conn.request("GET", "/api/status")
        resp = conn.getresponse()
        resp.read()
        samples.append((time.time(), (time.perf_counter() - t0) * 1e3))
        if resp.status not in (200, 503):
            errors.append(f"HTTP {resp.status}")
        time.sleep(max(0.0, next_t - time.perf_counter()))
    stop_sse.set()
    sse.join(timeout=2)
    conn.close()
    out.put({"samples": samples, "errors": errors[:10], "sse_events": counts.get("sse_events", 0)})


def bench_hmi(opts: BenchOptions) -> dict[str, Any]:
    """``opts.n`` sim cycles (default 2) with the HMI polled at 50 Hz; latencies of GET /api/status."""
    from cellctl.bench.reliability.sim_cell import FAST_SIM, running_sim_cell
    from cellctl.bus.session import private_bus_overrides

    n_cycles = opts.n or 2
    port = _free_port()
    samples: list[float] = []
    results: list[Any] = []
    errors: list[str] = []
    counts: dict[str, int] = {}
    # a private loopback port: the bench must not meet a cell someone runs on the default one
    with running_sim_cell(opts, "bench-hmi", [*FAST_SIM, *private_bus_overrides()]) as run:
        cfg, plc = run.cfg, run.plc
        hmi_yaml = run.out / "hmi.yaml"
        hmi_yaml.write_text(f"port: {port}\n")  # no users: the bench only reads
        sets = [a for ov in run.overrides for a in ("--set", ov)]
        cmd = [sys.executable, "-m", "cellctl", "hmi", "--hmi-config", str(hmi_yaml), *sets]
        if opts.config:
            cmd += ["--config", opts.config]
        log = open(run.out / "hmi.log", "wb")  # closed below
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        try:
            _wait_up(port, proc, run.out / "hmi.log").close()
            # The browser-like client is its own process too: in this one the daemon's threads
            # would add their GIL waits to what is measured.
            ctx = multiprocessing.get_context("spawn")
            stop, out = ctx.Event(), ctx.Queue()
            client = ctx.Process(target=_client, args=(port, RATE_HZ, stop, out), daemon=True)
            client.start()
            windows: list[tuple[float, float]] = []
            results: list[Any] = []
            try:
                for i in range(n_cycles):
                    plc.to_idle()
                    t0 = time.time()
                    results.append(plc.run_cycle(900))
                    windows.append((t0, time.time()))
                    print(f"bench hmi: cycle {i + 1}/{n_cycles}: {results[-1].outcome.value}", file=sys.stderr)
            except CellError as err:
                errors.append(str(err))
            stop.set()
            got = out.get(timeout=30)
            client.join(timeout=10)
            counts["sse_events"] = got["sse_events"]
            errors += got["errors"]
            samples = [dt for t, dt in got["samples"] if any(a <= t <= b for a, b in windows)]
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
            log.close()
    if errors or not samples:
        raise CellError(f"bench hmi failed: {errors[:3] or 'no samples'}")
    p99 = _percentile(samples, 0.99)
    return {
        "cycles": [
            {"cycle_id": r.cycle_id, "outcome": r.outcome.value, "viewpoints": len(r.viewpoints)} for r in results
        ],  # fmt: skip
        "requests": len(samples),
        "rate_hz": RATE_HZ,
        "sse_updates_received": counts.get("sse_events", 0),
        "status_latency_ms": {
            "p50": round(_percentile(samples, 0.5), 3),
            "p95": round(_percentile(samples, 0.95), 3),
            "p99": round(p99, 3),
            "max": round(max(samples), 3),
            "mean": round(statistics.fmean(samples), 3),
        },
        "target_p99_ms": TARGET_P99_MS,
        "meets_target": p99 <= TARGET_P99_MS,
        "setup": "daemon + sim workers (FAST_SIM) in the bench process, HMI in its own process, a client "
        "process with one SSE stream open and GET /api/status on one keep-alive connection; requests made "
        "while a cycle ran",
        "camera": f"{cfg.camera.width}x{cfg.camera.height}",
    }


def _wait_up(port: int, proc: subprocess.Popen, log: Path, timeout: float = 60.0) -> http.client.HTTPConnection:
    """A keep-alive connection once the HMI answers and sees the cell."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise CellError(f"cellctl hmi exited with {proc.returncode}: {log.read_text()[-600:]}")
        try:
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            conn.request("GET", "/api/status")
            r = conn.getresponse()
            r.read()
            if r.status == 200:
                return conn
            conn.close()
        except OSError:
            pass
        time.sleep(0.2)
    raise CellError(f"the HMI on port {port} did not see the cell within {timeout:g} s: {log.read_text()[-600:]}")
