"""ConfirmBaseParked over OPC UA (asyncua client): a PLC confirms a manual base's park, the cycle
goes on; a confirmation the cycle does not wait for, or a bad argument, is refused naming why."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

import pytest
from asyncua import ua

from cellctl.bus.plc_client import PlcClient
from cellctl.config import CellConfig, load_config
from tests.conftest import cfg_overrides, free_port
from tests.fakes.workers import FakeCell
from tests.gateway.conftest import PASSWORD, USER, Ua, wait_until

S = ua.StatusCodes
I32 = ua.VariantType.Int32


@pytest.fixture(scope="module")
def shared_cfg(tmp_path_factory: pytest.TempPathFactory) -> CellConfig:
    """This module's cell parks its base by hand: the approach waits for the confirmation."""
    tmp = tmp_path_factory.mktemp("gw-base")
    return load_config(None, [*cfg_overrides(tmp, free_port()), "base.backend=manual", "base.confirm_timeout_s=30"])


def run(coro: Any) -> Any:
    return asyncio.run(coro)


def test_a_plc_confirms_the_park_by_method_and_the_cycle_goes_on(cfg, daemon, gateway, spy, url) -> None:
    base = daemon.supervisor.cycles.base
    with FakeCell(cfg) as fake, PlcClient(cfg, "gw-base-test") as plc:

        async def refused_first() -> None:
            async with Ua(url, USER, PASSWORD) as c:
                st, reason = await c.call("ConfirmBaseParked", ua.Variant(0, I32), parent="")
                assert st.value == S.BadInvalidArgument and "not waiting for the base" in reason
                st, reason = await c.call("ConfirmBaseParked", ua.Variant(-1, I32), parent="")
                assert st.value == S.BadOutOfRange and "-1" in reason
                st, reason = await c.call("ConfirmBaseParked", ua.Variant("0", ua.VariantType.String), parent="")
                assert st.value == S.BadTypeMismatch
                st, reason = await c.call("ConfirmBaseParked", parent="")
                assert st.value == S.BadArgumentsMissing

        run(refused_first())
        assert plc.command("reset", timeout=10).accepted
        wait_until(lambda: plc.status().state == "Idle", 10, "Idle")
        assert plc.command("start", timeout=10).accepted
        wait_until(lambda: base.waiting == 0, 10, "the approach waiting for the base at station 0")
        assert "approach" not in fake.calls  # the arm waits for the base

        async def confirm() -> None:
            async with Ua(url, USER, PASSWORD) as c:
                st, reason = await c.call("ConfirmBaseParked", ua.Variant(1, I32), parent="")
                assert st.value == S.BadInvalidArgument and "waits for station 0" in reason
                st, reason = await c.call("ConfirmBaseParked", ua.Variant(0, I32), parent="")
                assert st.is_good(), reason
                assert reason == "" and await c.read("Status/CmdAccepted") is True

        run(confirm())
        wait_until(lambda: "approach" in fake.calls, 10, "the approach after the confirmation")
        assert base.waiting is None
        res = plc.results.get(timeout=30)
        assert res.outcome == "completed", res.reason
    sent = [json.loads(p) for p in spy.payloads]
    assert [p["base_parked"] for p in sent if p.get("base_parked") is not None] == [0, 1, 0]  # -1, "0" never left
    assert all(p["user"] == f"opcua:{USER}" for p in sent if p.get("base_parked") is not None)


def test_a_reader_cannot_confirm_a_park(gateway, spy, url) -> None:
    async def body() -> None:
        async with Ua(url) as c:  # anonymous: reads only
            with pytest.raises(ua.UaStatusCodeError) as err:
                await c.call("ConfirmBaseParked", ua.Variant(0, I32), parent="")
            assert err.value.code == S.BadUserAccessDenied

    run(body())
    time.sleep(0.2)
    assert spy.count == 0
