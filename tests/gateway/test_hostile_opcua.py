"""The OPC UA gateway under a hostile client (part of the hostile-client suite, `make test-all`; loopback).

Each case asserts that nothing reached the bus (the spy), the daemon did not move, and the gateway
still serves a new session. The seeded 2000-case write/call fuzz is `tests/gateway/test_fuzz.py`.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import socket
import time
from pathlib import Path

import pytest
from asyncua import Client, ua

from cellctl.config import CellConfig
from cellctl.gateway.opcua import OpcuaGateway
from cellctl.supervisor.definition import PackMLState
from tests.gateway.conftest import PASSWORD, USER, Ua, make_gw_cfg

pytestmark = pytest.mark.slow

V = ua.VariantType
S = ua.StatusCodes


def _unmoved(gateway: OpcuaGateway, spy, url: str) -> None:
    async def check() -> None:
        async with Ua(url) as anon:
            assert await anon.read("Status/StateCurrent") == PackMLState.Stopped

    asyncio.run(check())
    assert spy.count == 0


def test_types_and_ranges(gateway: OpcuaGateway, spy, url: str) -> None:
    async def body() -> None:
        async with Ua(url, USER, PASSWORD) as c:
            for value, vtype in [("1", V.String), (1.0, V.Double), (True, V.Boolean), (1, V.Int64), ([1], V.Int32),
                                 (b"\x01", V.ByteString), (None, V.Null)]:  # fmt: skip
                assert not (await c.write("Command/CntrlCmd", value, vtype)).is_good(), (value, vtype)
            for bad in (0, 11, -1, 2**31 - 1, -(2**31)):
                assert (await c.write("Command/CntrlCmd", bad, V.Int32)).value == S.BadOutOfRange
            for path, value in [("Command/Parameter/Surface", "roof"), ("Command/Parameter/Mode", "x" * 100_000)]:
                assert not (await c.write(path, value, V.String)).is_good(), path
            st, _ = await c.call("Start", ua.Variant(1, V.Int32))  # arguments to an argument-less method
            assert not st.is_good()
        async with Ua(url) as anon:  # anonymous: read only
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):  # refused as a whole service
                await anon.write("Command/CntrlCmd", 2, V.Int32)
            with pytest.raises(ua.UaError):
                await anon.call("Reset")

    asyncio.run(body())
    _unmoved(gateway, spy, url)


def test_sessions_and_raw_connections(gateway: OpcuaGateway, spy, url: str) -> None:
    host, port = gateway.cfg.host, gateway.cfg.port
    junk = [b"", b"HEL", b"HELF\xff\xff\xff\x7f" + b"\0" * 24, b"GET / HTTP/1.1\r\n\r\n", b"\x00" * 4096]
    socks = []
    for i in range(40):  # half-open connections and garbage, left hanging
        s = socket.create_connection((host, port), timeout=5)
        s.sendall(junk[i % len(junk)])
        socks.append(s)

    async def abandon() -> None:  # sessions created and activated, then the socket dropped without CloseSession
        for _ in range(10):
            c = Client(url, timeout=5)
            await c.connect()
            c.uaclient.protocol.transport.abort()  # type: ignore[union-attr]

    asyncio.run(abandon())
    t = time.perf_counter()
    _unmoved(gateway, spy, url)
    assert time.perf_counter() - t < 5
    for s in socks:
        s.close()


def test_brute_force_1000_guesses(cfg: CellConfig, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """1000 wrong passwords from 127.0.0.2 as fast as the attacker can (bounded at 180 s); the PLC at 127.0.0.3."""
    gw = OpcuaGateway(cfg, make_gw_cfg(tmp_path)).start_thread()
    url = gw.cfg.endpoint
    logging.getLogger("asyncua").setLevel(logging.ERROR)  # as `cellctl gateway opcua` runs it

    async def attack() -> tuple[int, float]:
        loop = asyncio.get_running_loop()
        loop.create_connection = functools.partial(loop.create_connection, local_addr=("127.0.0.2", 0))  # type: ignore[method-assign]
        t0, n = time.monotonic(), 0
        while n < 1000 and time.monotonic() - t0 < 180:
            c = Client(url, timeout=5)
            c.set_user(USER)
            c.set_password(f"guess-{n:04d}")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await c.connect()
            n += 1
        return n, time.monotonic() - t0

    try:
        with caplog.at_level(logging.WARNING):
            n, elapsed = asyncio.run(attack())
            t = time.perf_counter()

            async def plc() -> None:
                loop = asyncio.get_running_loop()
                loop.create_connection = functools.partial(loop.create_connection, local_addr=("127.0.0.3", 0))  # type: ignore[method-assign]
                async with Ua(url, USER, PASSWORD) as s:
                    assert await s.read("Admin/LoginFailures") >= 1

            asyncio.run(plc())
            plc_ms = (time.perf_counter() - t) * 1000
        lines = [r for r in caplog.records if r.name.startswith(("cellctl", "asyncua"))]
        c = gw.throttle.counters
        th = gw.throttle
        charged = sum(th._backoff("pair", k) for k in range(1, c.failures + 1))
        to_check_all = sum(th._backoff("pair", k) for k in range(1, n + 1))
        print(f"OPC UA: {n} guesses in {elapsed:.1f} s: {c.failures} checked, {c.throttled} refused unchecked; "
              f"back-off charged {charged:.0f} s (checking all {n} would cost {to_check_all:.0f} s); "
              f"{len(lines)} log lines; PLC from another address in {plc_ms:.0f} ms")  # fmt: skip
        assert n == 1000, (n, elapsed)
        assert c.failures + c.throttled == 1000 and c.failures < 20
        for r in lines:
            print("  log:", r.name, r.getMessage()[:160])
        assert to_check_all >= 60 and len(lines) <= 20, [r.getMessage() for r in lines]
        assert plc_ms < 3000
    finally:
        gw.close()
