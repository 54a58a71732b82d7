"""Through the OPC UA gateway (issue 35): the shipped whole-bin cycle is `clean` when each surface is seen
enough, and a cycle made partial (one surface by config, or part of the inside seen) reaches the PLC as
`incomplete` with each surface's seen share and the minimum it missed; a real daemon, worker doubles, an
asyncua client."""

from __future__ import annotations

import asyncio

import pytest

from cellctl.gateway.opcua import OpcuaGateway
from cellctl.supervisor.definition import PackMLState
from tests.fakes.workers import FakeCell
from tests.gateway.conftest import PASSWORD, USER, Ua
from tests.supervisor.test_station_loop import faces as faces  # the case-study faces per surface
from tests.supervisor.test_whole_default import WideWholeFakeCell

SHIPPED = {"external": 0.6, "internal": 0.6}


@pytest.fixture
def shipped_minimum(cfg):  # the module's daemon gates on the shipped minimum for one test
    cfg.classifier.verdict.min_seen_fraction = dict(SHIPPED)
    yield cfg
    cfg.classifier.verdict.min_seen_fraction = {}


@pytest.fixture
def shipped(shipped_minimum):  # and the shipped whole-bin cycle (the conftest pins one station)
    shipped_minimum.planner.whole.enabled = True
    yield shipped_minimum
    shipped_minimum.planner.whole.enabled = False


async def _cycle(url: str) -> dict:
    """Reset, Start, wait for Complete through OPC UA; the LastCycle values then."""
    async with Ua(url, USER, PASSWORD) as c:
        st, _ = await c.call("Reset")
        assert st.is_good()
        await c.wait_value("Status/StateCurrent", PackMLState.Idle)
        id_before = await c.read("Admin/LastCycle/CycleId")
        st, _ = await c.call("Start")
        assert st.is_good()
        await c.wait_value("Status/StateCurrent", PackMLState.Complete, 30)
        for _ in range(250):  # the result may land just after the state
            if await c.read("Admin/LastCycle/CycleId") != id_before:
                break
            await asyncio.sleep(0.02)
        paths = ("Outcome", "Verdict", "Seen/external", "Seen/internal", "MinSeen/internal")
        return {p: await c.read(f"Admin/LastCycle/{p}") for p in paths}


def test_the_shipped_whole_bin_cycle_is_clean_only_when_each_surface_is_seen(shipped, gateway, url, faces) -> None:
    with WideWholeFakeCell(shipped, faces):  # three stations, every face of both surfaces seen
        seen_all = asyncio.run(_cycle(url))

    class Partial(WideWholeFakeCell):
        internal_share = 0.3

    with Partial(shipped, faces):
        partial = asyncio.run(_cycle(url))
    assert seen_all["Outcome"] == partial["Outcome"] == "completed"
    assert seen_all["Verdict"] == "clean" and seen_all["Seen/external"] == pytest.approx(1.0)
    assert seen_all["Seen/internal"] == pytest.approx(1.0)
    assert partial["Verdict"] == "incomplete" and 0 < partial["Seen/internal"] < partial["MinSeen/internal"] == 0.6


def test_a_one_surface_cycle_is_incomplete_on_the_plc_side(shipped_minimum, gateway: OpcuaGateway, url: str) -> None:
    with FakeCell(shipped_minimum):  # single-station doubles (the conftest's pin): six external faces seen
        got = asyncio.run(_cycle(url))
    assert got["Outcome"] == "completed" and got["Verdict"] == "incomplete"
    assert 0 < got["Seen/external"] < 0.01 and got["Seen/internal"] == 0.0 and got["MinSeen/internal"] == 0.6
