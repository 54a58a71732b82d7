"""OPC UA logins are throttled per (user, client address) and per address; the PLC elsewhere is not slowed."""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from pathlib import Path

import pytest
from asyncua import Client, ua

from cellctl.config import CellConfig
from cellctl.gateway.opcua import OpcuaGateway
from tests.gateway.conftest import PASSWORD, USER, Ua, make_gw_cfg


class FrozenClock:
    """The gateway's throttle clock: time stands still, so a back-off lasts the whole test."""

    def __init__(self) -> None:
        self.t = 5000.0

    def __call__(self) -> float:
        return self.t


async def login(url: str, source: str, password: str) -> bool:
    """One session from client address ``source`` (a loopback alias); True if it was activated."""
    loop = asyncio.get_running_loop()
    loop.create_connection = functools.partial(loop.create_connection, local_addr=(source, 0))  # type: ignore[method-assign]
    client = Client(url, timeout=10)
    client.set_user(USER)
    client.set_password(password)
    try:
        await client.connect()
    except ua.uaerrors.BadUserAccessDenied:
        return False
    await client.disconnect()
    return True


@pytest.fixture
def throttled_gateway(cfg: CellConfig, tmp_path: Path):
    clock = FrozenClock()
    gw_cfg = make_gw_cfg(tmp_path, "login.pair_free=3", "login.address_free=10")
    gw = OpcuaGateway(cfg, gw_cfg, clock=clock).start_thread()
    try:
        yield gw, clock
    finally:
        gw.close()


def test_guesses_back_off_per_address_and_the_plc_elsewhere_connects_at_once(
    throttled_gateway,
    caplog: pytest.LogCaptureFixture,
) -> None:
    gw, clock = throttled_gateway
    url = gw.cfg.endpoint
    logging.getLogger("asyncua").setLevel(logging.ERROR)  # as `cellctl gateway opcua` runs it
    with caplog.at_level(logging.WARNING):
        results = [asyncio.run(login(url, "127.0.0.2", f"guess-{i}")) for i in range(20)]
        right_from_attacker = asyncio.run(login(url, "127.0.0.2", PASSWORD))
        t = time.perf_counter()
        plc_elsewhere = asyncio.run(login(url, "127.0.0.3", PASSWORD))
        plc_s = time.perf_counter() - t
    lines = [r for r in caplog.records if r.name.startswith(("cellctl", "asyncua"))]
    assert results == [False] * 20
    assert not right_from_attacker, "the right password from the guessing address must wait out the back-off"
    assert plc_elsewhere and plc_s < 3.0, plc_s
    c = gw.throttle.counters
    assert (c.failures, c.throttled, c.lockouts) == (3, 18, 1)
    assert len(lines) <= 2, [r.getMessage() for r in lines]  # main: two lines per guess
    clock.t += 1.0  # the first back-off (1 s) has passed: the pair may try again
    assert asyncio.run(login(url, "127.0.0.2", PASSWORD))

    async def admin() -> tuple[int, int]:
        async with Ua(url, USER, PASSWORD) as s:
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                got = (await s.read("Admin/LoginFailures"), await s.read("Admin/LoginsThrottled"))
                if got == (3, 18):
                    break
                await asyncio.sleep(0.1)
            return got

    assert asyncio.run(admin()) == (3, 18)
