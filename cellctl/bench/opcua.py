"""``cellctl bench opcua``: command → ``StateCurrent`` change through the gateway, beside the same over raw Zenoh.

A daemon (no workers) and the gateway run as their own processes on private loopback ports, as in
a plant. Each round sends one command per path, alternating Reset (Stopped → Resetting) and Stop
(Idle → Stopping), and times from just before the request to the arrival of the first StateCurrent
that differs from the wait state: by an OPC UA subscription (method call, or the PackTags handshake
as one Write of CntrlCmd + CmdChangeRequest) and by a Zenoh subscriber on ``status`` (query on ``cmd``).
Paths take turns in blocks of 10 commands, so load on the machine touches all of them alike, and
only the measured path's subscription is open (the bench's client parses nothing else meanwhile).
"""

from __future__ import annotations

import asyncio
import json
import os
import queue
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.errors import CellError

__all__ = ["bench_opcua"]

IDLE, STOPPED = 4, 2
TARGET_P99_MS = 20.0


def _pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def _summary(xs: list[float]) -> dict[str, float | int]:
    return {
        "p50_ms": round(_pct(xs, 0.5), 2),
        "p99_ms": round(_pct(xs, 0.99), 2),
        "max_ms": round(max(xs), 2),
        "n": len(xs),
    }


class _UaPath:
    """One asyncua session with a StateCurrent subscription at ``interval_ms``."""

    def __init__(self, url: str, user: str, password: str, interval_ms: float, how: str) -> None:
        from asyncua import Client

        self.client = Client(url, timeout=10)
        self.client.set_user(user)
        self.client.set_password(password)
        self.interval_ms = interval_ms
        self.how = how
        self.changes: asyncio.Queue[tuple[float, int]] = asyncio.Queue()
        self.samples: list[float] = []

    async def open(self) -> None:
        from asyncua import ua

        await self.client.connect()
        self.ns = await self.client.get_namespace_index("urn:cellctl:opcua")
        self.ua = ua
        path = self

        class Handler:
            def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
                path.changes.put_nowait((time.perf_counter(), val))

        self._handler = Handler()
        self.sub: Any = None

    async def subscribe(self) -> None:
        self.sub = await self.client.create_subscription(self.interval_ms, self._handler)
        await self.sub.subscribe_data_change(self.client.get_node(self._id("Status/StateCurrent")))

    async def unsubscribe(self) -> None:
        await self.sub.delete()
        self.sub = None

    def _id(self, p: str) -> Any:
        return self.ua.NodeId(f"cell1/{p}", self.ns)

    async def _next_change(self, timeout: float) -> tuple[float, int]:
        return await asyncio.wait_for(self.changes.get(), timeout)

    async def settle(self, state: int) -> None:
        """Drain notifications until StateCurrent reads ``state``."""
        node = self.client.get_node(self._id("Status/StateCurrent"))
        deadline = time.monotonic() + 15
        while await node.read_value() != state:
            if time.monotonic() > deadline:
                raise CellError(f"StateCurrent did not reach {state}")
            await asyncio.sleep(0.005)
        await asyncio.sleep(2 * self.interval_ms / 1000 + 0.01)
        while not self.changes.empty():
            self.changes.get_nowait()

    async def one(self, state: int) -> None:
        ua = self.ua
        code = 1 if state == STOPPED else 3
        await self.settle(state)
        t0 = time.perf_counter()
        if self.how == "method":
            name = "Reset" if code == 1 else "Stop"
            req = ua.CallMethodRequest(
                ObjectId=self._id("BaseStateMachine"), MethodId=self._id(f"BaseStateMachine/{name}")
            )
            res = (await self.client.uaclient.call([req]))[0]
            status = res.StatusCode
        else:
            params = ua.WriteParameters()
            params.NodesToWrite = [
                ua.WriteValue(
                    NodeId=self._id("Command/CntrlCmd"),
                    AttributeId=ua.AttributeIds.Value,
                    Value=ua.DataValue(ua.Variant(code, ua.VariantType.Int32)),
                ),
                ua.WriteValue(
                    NodeId=self._id("Command/CmdChangeRequest"),
                    AttributeId=ua.AttributeIds.Value,
                    Value=ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)),
                ),
            ]
            status = (await self.client.uaclient.write(params))[1]
        if not status.is_good():
            raise CellError(f"command {code} refused through OPC UA: {status.name}")
        while True:
            t1, val = await self._next_change(10)
            if val != state:
                self.samples.append((t1 - t0) * 1000)
                return

    async def close(self) -> None:
        await self.client.disconnect()


class _ZenohPath:
    """A raw Zenoh client: query on cmd, Status by subscription (what a Zenoh-speaking PLC sees)."""

    def __init__(self, endpoint: str) -> None:
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.states: queue.Queue[tuple[float, int]] = queue.Queue()
        self.sub = self.session.declare_subscriber(
            "cell/cell1/status",
            lambda s: self.states.put((time.perf_counter(), json.loads(s.payload.to_bytes())["state_code"])),
        )
        self.samples: list[float] = []
        self.seq = 0

    def one(self, state: int) -> int:
        """One command from wait state ``state``; returns the wait state it leads to, once reached."""
        while not self.states.empty():
            self.states.get_nowait()
        code = 1 if state == STOPPED else 3
        self.seq += 1
        body = json.dumps({"type": "cellctl/Command", "v": 1, "cntrl_cmd": code, "request_id": f"bench-{self.seq}"})
        t0 = time.perf_counter()
        replies = list(self.session.get("cell/cell1/cmd", payload=body, timeout=10))
        if not replies or replies[0].ok is None or not json.loads(replies[0].ok.payload.to_bytes())["accepted"]:
            raise CellError(f"command {code} not accepted over Zenoh")
        while True:
            t1, val = self.states.get(timeout=10)
            if val != state:
                self.samples.append((t1 - t0) * 1000)
                break
        target = IDLE if state == STOPPED else STOPPED
        while val != target:
            _, val = self.states.get(timeout=10)
        return target

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


def _start(cmd: list[str], log: Path) -> subprocess.Popen[bytes]:
    f = open(log, "wb")  # kept open for the child's life
    return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)


def _stop(p: subprocess.Popen[bytes]) -> int | None:
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
        try:
            return p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
    return p.wait()


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def _measure(url: str, user: str, password: str, zenoh_ep: str, n: int, block: int = 10) -> dict[str, Any]:
    paths = {
        "opcua": _UaPath(url, user, password, 0, "method"),
        "opcua_handshake": _UaPath(url, user, password, 0, "handshake"),
        "opcua_10ms": _UaPath(url, user, password, 10, "method"),
    }
    for p in paths.values():
        await p.open()
    z = _ZenohPath(zenoh_ep)
    loop = asyncio.get_running_loop()
    probe = paths["opcua"]
    state_node = probe.client.get_node(probe._id("Status/StateCurrent"))

    async def wait_state() -> int:
        state = await state_node.read_value()
        while state not in (IDLE, STOPPED):
            await asyncio.sleep(0.005)
            state = await state_node.read_value()
        return state

    try:
        # Blocks of `block` commands per path, paths in turn: only the measured path's subscription
        # is open, so the bench's own client does not parse the others' notifications meanwhile.
        done = 0
        while done < n:
            k = min(block, n - done)
            for path in paths.values():
                await path.subscribe()
                for _ in range(k):
                    await path.one(await wait_state())
                await path.unsubscribe()
            state = await wait_state()
            for _ in range(k):
                state = await loop.run_in_executor(None, z.one, state)
            await probe.settle(state)  # the gateway's view catches up before the next OPC UA block
            done += k
            if done % 50 == 0:
                print(f"bench opcua: {done}/{n} rounds", file=sys.stderr)
    finally:
        z.close()
        for p in paths.values():
            await p.close()
    out: dict[str, Any] = {name: _summary(p.samples) for name, p in paths.items()}
    out["zenoh"] = _summary(z.samples)
    return out


def bench_opcua(opts: BenchOptions) -> dict[str, Any]:
    """Run the bench (``opts.n`` rounds, default 200; each round is one command per path)."""
    n = opts.n or 200
    out_dir = Path(tempfile.mkdtemp(prefix="cellctl-bench-opcua-"))
    bus_port, ua_port = _free_port(), _free_port()
    ep = f"tcp/127.0.0.1:{bus_port}"
    password = secrets.token_urlsafe(16)
    (out_dir / "users").write_text(f"bench:{password}\n")
    sets = [
        f'bus.listen=["{ep}"]',
        f'bus.connect=["{ep}"]',
        f"recording.dir={out_dir / 'logs'}",
        f"recording.index={out_dir / 'cells.db'}",
        *opts.overrides,
    ]
    set_args = [a for s in sets for a in ("--set", s)]
    py = [sys.executable, "-m", "cellctl"]
    cfg_args = ["--config", opts.config] if opts.config else []
    url = f"opc.tcp://127.0.0.1:{ua_port}"
    daemon = _start([*py, "run", *cfg_args, *set_args], out_dir / "daemon.log")
    gateway = _start(
        [*py, "gateway", "opcua", *cfg_args, *set_args, "--gw-set", f"endpoint={url}",
         "--gw-set", f"users_file={out_dir / 'users'}"],
        out_dir / "gateway.log",
    )  # fmt: skip
    try:

        async def ready() -> None:
            from asyncua import Client

            deadline = time.monotonic() + 120
            while True:
                try:
                    async with Client(url, timeout=5) as c:
                        ns = await c.get_namespace_index("urn:cellctl:opcua")
                        from asyncua import ua

                        node = c.get_node(ua.NodeId("cell1/Status/StateCurrent", ns))
                        while await node.read_value() != STOPPED:
                            if time.monotonic() > deadline:
                                raise CellError("the gateway never showed the daemon in Stopped")
                            await asyncio.sleep(0.1)
                        return
                except (OSError, asyncio.TimeoutError, ConnectionError):
                    if daemon.poll() is not None or gateway.poll() is not None or time.monotonic() > deadline:
                        raise CellError(f"daemon or gateway did not come up; see {out_dir}") from None
                    await asyncio.sleep(0.3)

        asyncio.run(ready())
        load_start = os.getloadavg()[0]
        print(f"bench opcua: {n} rounds, gateway {url}, daemon {ep}", file=sys.stderr)
        result = asyncio.run(_measure(url, "bench", password, ep, n))
    finally:
        rc = {"daemon": _stop(daemon), "gateway": _stop(gateway)}
    load = os.getloadavg()
    return {
        **result,
        "target_p99_ms": TARGET_P99_MS,
        "opcua_meets_target": result["opcua"]["p99_ms"] <= TARGET_P99_MS,
        "what": "request sent -> first StateCurrent != the wait state received by the client's subscription",
        "publishing_interval_ms": {"opcua": 0, "opcua_handshake": 0, "opcua_10ms": 10},
        "commands": "alternating Reset (Stopped->Resetting) and Stop (Idle->Stopping), daemon without workers",
        "exit_codes": rc,
        "cpus": os.cpu_count(),
        "loadavg_1m_at_start": round(load_start, 2),
        "loadavg_1m_at_end": round(load[0], 2),
        "logs": str(out_dir),
    }
