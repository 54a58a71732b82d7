"""A partial cycle reaches the PLC as `incomplete` through the OPC UA gateway, with each surface's seen
share and the minimum it missed (issue 35); a real daemon, worker doubles, an asyncua client."""

from __future__ import annotations

import asyncio

import pytest

from cellctl.gateway.opcua import OpcuaGateway
from cellctl.supervisor.definition import PackMLState
from tests.fakes.workers import FakeCell
from tests.gateway.conftest import PASSWORD, USER, Ua

SHIPPED = {"external": 0.6, "internal": 0.6}


@pytest.fixture
def shipped_minimum(cfg):  # noqa: ANN001, ANN201 - the module's daemon gates on the shipped minimum for one test
    cfg.classifier.verdict.min_seen_fraction = dict(SHIPPED)
    yield cfg
    cfg.classifier.verdict.min_seen_fraction = {}


def test_a_one_surface_cycle_is_incomplete_on_the_plc_side(shipped_minimum, gateway: OpcuaGateway, url: str) -> None:  # noqa: ANN001
    async def body() -> dict:
        async with Ua(url, USER, PASSWORD) as c:
            assert (await c.read("Admin/LastCycle/Seen/internal")) == -1.0  # no cycle yet: unknown
            st, _ = await c.call("Reset")
            assert st.is_good()
            await c.wait_value("Status/StateCurrent", PackMLState.Idle)
            st, _ = await c.call("Start")
            assert st.is_good()
            await c.wait_value("Status/StateCurrent", PackMLState.Complete, 30)
            await c.wait_value("Admin/LastCycle/Verdict", "incomplete")
            paths = ("Outcome", "Seen/external", "Seen/internal", "MinSeen/external", "MinSeen/internal")
            return {p: await c.read(f"Admin/LastCycle/{p}") for p in paths}

    with FakeCell(shipped_minimum):  # single-station doubles (the conftest's pin): six external faces seen
        got = asyncio.run(body())
    assert got["Outcome"] == "completed"
    assert 0 < got["Seen/external"] < 0.01 and got["Seen/internal"] == 0.0
    assert got["MinSeen/external"] == got["MinSeen/internal"] == 0.6
