"""The gateway against a real daemon, driven by an asyncua client the way a PLC would drive it."""

from __future__ import annotations

import asyncio
import datetime as dt
import json

import pytest
from asyncua import Client, ua

from cellctl.gateway.opcua import CELLCTL_NS, PACKML_NS, OpcuaGateway
from cellctl.supervisor.definition import PackMLState
from tests.fakes.workers import FakeCell
from tests.gateway.conftest import PASSWORD, USER, Ua, make_daemon, wait_until

S = ua.StatusCodes
I32, BOOL = ua.VariantType.Int32, ua.VariantType.Boolean


def run(coro):
    return asyncio.run(coro)


def test_browse_paths_namespaces_and_initial_values(gateway: OpcuaGateway, url: str) -> None:
    async def body() -> None:
        async with Client(url) as c:
            cc = await c.get_namespace_index(CELLCTL_NS)
            pk = await c.get_namespace_index(PACKML_NS)
            sc = await c.nodes.objects.get_child([f"{cc}:cell1", f"{pk}:Status", f"{cc}:StateCurrent"])
            assert sc.nodeid == ua.NodeId("cell1/Status/StateCurrent", cc)
            dv = await sc.read_data_value()
            assert dv.Value.VariantType == I32 and dv.Value.Value == PackMLState.Stopped == 2
            assert dv.SourceTimestamp is not None
            assert abs((dv.SourceTimestamp.replace(tzinfo=dt.UTC) - dt.datetime.now(dt.UTC)).total_seconds()) < 30
            mode = await c.nodes.objects.get_child([f"{cc}:cell1", f"{pk}:Status", f"{pk}:UnitModeCurrent"])
            assert await mode.read_value() == 1  # Production
            count = await c.nodes.objects.get_child([f"{cc}:cell1", f"{pk}:Admin", f"{pk}:ProdProcessedCount"])
            assert (await count.read_data_value()).Value.VariantType == I32
            sm = await c.nodes.objects.get_child([f"{cc}:cell1", f"{pk}:BaseStateMachine"])
            names = {(await m.read_browse_name()).Name for m in await sm.get_methods()}
            assert names == {"Reset", "Start", "Stop", "Hold", "Unhold", "Suspend", "Unsuspend", "Abort", "Clear",
                             "ToComplete"}  # fmt: skip
            cur = await sm.get_child(["0:CurrentState"])
            assert (await cur.read_value()).Text == "Stopped"
            cmd = await c.nodes.objects.get_child([f"{cc}:cell1", f"{cc}:Command", f"{cc}:CntrlCmd"])
            assert cmd.nodeid == ua.NodeId("cell1/Command/CntrlCmd", cc)

    run(body())


def test_methods_return_the_ack_and_rejects_change_nothing(gateway: OpcuaGateway, spy, url: str) -> None:
    async def body() -> None:
        async with Ua(url, USER, PASSWORD) as c:
            st, reason = await c.call("Reset")
            assert st.is_good() and reason == ""
            await c.wait_value("Status/StateCurrent", PackMLState.Idle)
            assert await c.read("Status/StateRequested") == PackMLState.Resetting
            assert await c.read("Status/CmdAccepted") is True
            st, reason = await c.call("Reset")
            assert st.value == S.BadInvalidState
            assert "'reset' is not allowed in state 'Idle'" in reason
            assert await c.read("Status/CmdRejectReason") == reason
            assert await c.read("Status/CmdAccepted") is False
            st, reason = await c.call("Clear")
            assert st.value == S.BadInvalidState and "Idle" in reason
            # refused before the bus: arguments where none belong, a foreign object id
            st, reason = await c.call("Stop", ua.Variant(1, I32))
            assert st.value == S.BadTooManyArguments
            req = ua.CallMethodRequest(ObjectId=c.id("Admin"), MethodId=c.id("BaseStateMachine/Stop"))
            assert (await c.client.uaclient.call([req]))[0].StatusCode.value == S.BadMethodInvalid
            await asyncio.sleep(0.3)
            assert await c.read("Status/StateCurrent") == PackMLState.Idle

    run(body())
    assert spy.count == 3  # Reset, Reset (refused by the daemon), Clear (refused by the daemon)
    sent = [json.loads(p) for p in spy.payloads]
    assert [p["cntrl_cmd"] for p in sent] == [1, 1, 9]
    assert {p["user"] for p in sent} == {f"opcua:{USER}"}
    assert gateway.commands_sent == 3


def test_handshake_and_bad_writes(gateway: OpcuaGateway, spy, url: str) -> None:
    async def body() -> None:
        async with Ua(url, USER, PASSWORD) as c:
            for bad in (0, 11, -1, 2**31 - 1, -(2**31)):
                assert (await c.write("Command/CntrlCmd", bad, I32)).value == S.BadOutOfRange, bad
            assert (await c.write("Command/CntrlCmd", 1.0, ua.VariantType.Double)).value == S.BadTypeMismatch
            assert (await c.write("Command/CntrlCmd", 1, ua.VariantType.Int16)).value == S.BadTypeMismatch
            assert (await c.write("Command/CntrlCmd", "1", ua.VariantType.String)).value == S.BadTypeMismatch
            assert (await c.write("Command/CntrlCmd", [1, 2], I32)).value == S.BadTypeMismatch
            assert (await c.write("Command/CmdChangeRequest", 1, I32)).value == S.BadTypeMismatch
            assert (await c.write("Command/Parameter/Mode", "fast", ua.VariantType.String)).value == S.BadOutOfRange
            assert (await c.write("Command/UnitMode", 4, I32)).value == S.BadOutOfRange
            # CmdChangeRequest without a command
            assert (await c.write("Command/CmdChangeRequest", True, BOOL)).value == S.BadNothingToDo
            assert "without a command" in await c.read("Status/CmdRejectReason")
            assert await c.read("Command/CmdChangeRequest") is False
            # status tags are read-only even to a commanding user
            assert (await c.write("Status/StateCurrent", 4, I32)).value == S.BadUserAccessDenied
            assert await c.read("Status/StateCurrent") == PackMLState.Stopped
            assert spy.count == 0
            # the real handshake
            assert (await c.handshake(1)).is_good()
            assert await c.read("Command/CmdChangeRequest") is False  # reset by the server once handled
            assert await c.read("Command/CntrlCmd") == 0
            assert await c.read("Status/CmdAccepted") is True
            await c.wait_value("Status/StateCurrent", PackMLState.Idle)
            st = await c.handshake(9)  # Clear in Idle: refused by the daemon
            assert st.value == S.BadInvalidState
            assert "'clear' is not allowed" in await c.read("Status/CmdRejectReason")
            assert await c.read("Command/CmdChangeRequest") is False
            # unit mode by handshake and by method
            assert (await c.write("Command/UnitMode", 2, I32)).is_good()
            assert (await c.write("Command/UnitModeChangeRequest", True, BOOL)).is_good()
            await c.wait_value("Status/UnitModeCurrent", 2)
            st, reason = await c.call("SetUnitMode", ua.Variant(7, I32), parent="")
            assert st.value == S.BadOutOfRange and "7" in reason
            st, reason = await c.call("SetUnitMode", ua.Variant("1", ua.VariantType.String), parent="")
            assert st.value == S.BadTypeMismatch
            st, reason = await c.call("SetUnitMode", ua.Variant(1, I32), parent="")
            assert st.is_good(), reason
            await c.wait_value("Status/UnitModeCurrent", 1)

    run(body())
    assert [json.loads(p).get("cntrl_cmd") or json.loads(p).get("unit_mode_code") for p in spy.payloads] == [1, 9, 2, 1]


def test_commands_carry_the_gateways_stamp_and_the_supervisor_checks_it(gateway, spy, url, monkeypatch) -> None:
    hour_ago = (dt.datetime.now(dt.UTC) - dt.timedelta(hours=1)).isoformat()

    async def body() -> None:
        async with Ua(url, USER, PASSWORD) as c:
            assert (await c.call("Reset"))[0].is_good()
            await c.wait_value("Status/StateCurrent", PackMLState.Idle)
            # a gateway whose clock is an hour behind: its otherwise valid Stop is refused as stale
            monkeypatch.setattr("cellctl.gateway.opcua.server.now_iso", lambda: hour_ago)
            st, reason = await c.call("Stop")
            assert st.value == S.BadInvalidArgument and "s old" in reason
            await asyncio.sleep(0.3)
            assert await c.read("Status/StateCurrent") == PackMLState.Idle

    run(body())
    fresh, stale = (json.loads(p)["stamp"] for p in spy.payloads)
    assert abs((dt.datetime.now(dt.UTC) - dt.datetime.fromisoformat(fresh)).total_seconds()) < 30
    assert stale == hour_ago


def test_start_params_travel_with_start(gateway: OpcuaGateway, spy, url: str) -> None:
    async def body() -> None:
        async with Ua(url, USER, PASSWORD) as c:
            assert (await c.call("Reset"))[0].is_good()
            await c.wait_value("Status/StateCurrent", PackMLState.Idle)
            assert (await c.write("Command/Parameter/Mode", "collect", ua.VariantType.String)).is_good()
            st, reason = await c.call("Start")  # collect mode without a label: the daemon refuses
            assert st.value == S.BadInvalidArgument and "label" in reason
            assert await c.read("Status/StateCurrent") == PackMLState.Idle
            assert (await c.write("Command/Parameter/Mode", "", ua.VariantType.String)).is_good()

    run(body())
    assert json.loads(spy.payloads[-1])["params"] == {"mode": "collect"}


def test_anonymous_may_read_but_not_write_or_call(gateway: OpcuaGateway, spy, url: str) -> None:
    async def body() -> None:
        async with Ua(url) as c:
            assert await c.read("Status/StateCurrent") == PackMLState.Stopped
            with pytest.raises(ua.UaStatusCodeError) as err:
                await c.write("Command/CntrlCmd", 1, I32)
            assert err.value.code == S.BadUserAccessDenied
            with pytest.raises(ua.UaStatusCodeError) as err:
                await c.call("Reset")
            assert err.value.code == S.BadUserAccessDenied
        with pytest.raises(ua.UaStatusCodeError) as err:
            async with Ua(url, USER, "wrong password"):
                pass
        assert err.value.code == S.BadUserAccessDenied

    run(body())
    assert spy.count == 0


def test_subscription_sees_the_acting_states(gateway: OpcuaGateway, url: str) -> None:
    async def body() -> list[int]:
        seen: list[int] = []

        class Handler:
            def datachange_notification(self, node, val, data) -> None:
                seen.append(val)

        async with Ua(url, USER, PASSWORD) as c:
            sub = await c.client.create_subscription(10, Handler())
            # a queue, so that two changes inside one publishing interval both arrive
            await sub.subscribe_data_change(c.client.get_node(c.id("Status/StateCurrent")), queuesize=10)
            await asyncio.sleep(0.3)
            assert (await c.call("Reset"))[0].is_good()
            deadline = asyncio.get_running_loop().time() + 10
            while PackMLState.Idle not in seen and asyncio.get_running_loop().time() < deadline:
                await asyncio.sleep(0.02)
            await sub.delete()
        return seen

    seen = run(body())
    assert seen[0] == PackMLState.Stopped  # the initial value
    assert seen[-1] == PackMLState.Idle
    assert PackMLState.Resetting in seen


@pytest.mark.parametrize("how", ["handshake", "methods"])
def test_sim_cycle_counts_in_admin(cfg, gateway: OpcuaGateway, url: str, how: str) -> None:
    async def command(c: Ua, name: str) -> None:
        code = {"Reset": 1, "Start": 2}[name]
        st = await c.handshake(code) if how == "handshake" else (await c.call(name))[0]
        assert st.is_good(), (name, st, await c.read("Status/CmdRejectReason"))

    async def body() -> None:
        async with Ua(url, USER, PASSWORD) as c:
            before = await c.read("Admin/ProdProcessedCount")
            defective = await c.read("Admin/ProdDefectiveCount")
            await command(c, "Reset")
            await c.wait_value("Status/StateCurrent", PackMLState.Idle)
            await command(c, "Start")
            await c.wait_value("Status/StateCurrent", PackMLState.Complete, 30)
            await c.wait_value("Admin/ProdProcessedCount", before + 1)
            assert await c.read("Admin/ProdDefectiveCount") == defective + 1
            assert await c.read("Admin/LastCycle/Outcome") == "completed"
            assert await c.read("Admin/LastCycle/Verdict") == "dirty"
            assert (await c.read("Admin/LastCycle/CycleId")).startswith(await c.read("Status/CycleId") or "")
            assert await c.read("Admin/Workers/robot") is True

    with FakeCell(cfg, dirty_viewpoints={1}):
        wait_until(lambda: gateway._values.get(gateway._spaces["cell1"].nodeid("Admin/Workers/planner")), 10)
        run(body())


def test_daemon_down_then_back(own_cfgs) -> None:
    cfg, gw_cfg = own_cfgs
    url = gw_cfg.endpoint
    cell = make_daemon(cfg)
    gw = OpcuaGateway(cfg, gw_cfg).start_thread()
    try:
        wait_until(lambda: gw._down.get("cell1") is None, 10)
        cell.close()

        async def down() -> None:
            async with Ua(url, USER, PASSWORD) as c:
                await c.wait_value("Status/StateCurrent", PackMLState.Undefined, 10)
                assert await c.read("Status/DaemonConnected") is False
                assert "daemon down" in await c.read("Status/UnavailableReason")
                assert await c.read("Status/UnitModeCurrent") == 0
                st, reason = await c.call("Reset")
                assert st.value in (S.BadCommunicationError, S.BadTimeout) and reason

        run(down())
        cell = make_daemon(cfg)

        async def back() -> None:
            async with Ua(url, USER, PASSWORD) as c:
                await c.wait_value("Status/StateCurrent", PackMLState.Stopped, 20)
                assert await c.read("Status/UnavailableReason") == ""
                assert (await c.call("Reset"))[0].is_good()

        run(back())
    finally:
        gw.close()
        cell.close()


def test_gateway_waits_for_a_daemon_that_is_not_there_yet(own_cfgs) -> None:
    cfg, gw_cfg = own_cfgs
    url = gw_cfg.endpoint
    gw = OpcuaGateway(cfg, gw_cfg).start_thread()
    cell = None
    try:

        async def waiting() -> None:
            async with Ua(url) as c:
                assert await c.read("Status/StateCurrent") == 0
                assert "not connected to the cell bus" in await c.read("Status/UnavailableReason")

        run(waiting())
        cell = make_daemon(cfg)
        wait_until(lambda: gw._down.get("cell1") is None, 20, "the gateway connected to the late daemon")
    finally:
        gw.close()
        if cell is not None:
            cell.close()


def test_write_burst_gives_one_command_per_forwarded_request(gateway: OpcuaGateway, spy, url: str) -> None:
    async def one(i: int) -> list[ua.StatusCode]:
        async with Ua(url, USER, PASSWORD) as c:
            out = []
            for k in range(10):
                params = ua.WriteParameters()
                code = (i + k) % 12  # 0 and 11 are out of range
                params.NodesToWrite = [
                    ua.WriteValue(NodeId=c.id("Command/CntrlCmd"), AttributeId=ua.AttributeIds.Value,
                                  Value=ua.DataValue(ua.Variant(code, I32))),
                    ua.WriteValue(NodeId=c.id("Command/CmdChangeRequest"), AttributeId=ua.AttributeIds.Value,
                                  Value=ua.DataValue(ua.Variant(True, BOOL))),
                ]  # fmt: skip
                out.append((await c.client.uaclient.write(params))[1])
            return out

    async def body() -> list[ua.StatusCode]:
        results = await asyncio.gather(*(one(i) for i in range(4)))
        return [r for rs in results for r in rs]

    results = run(body())
    local = {S.BadNothingToDo, S.BadOutOfRange, S.BadTypeMismatch}
    forwarded = [r for r in results if r.value not in local]
    assert len(results) == 40 and forwarded
    assert spy.count == len(forwarded) == gateway.commands_sent


def test_client_that_disconnects_mid_call(gateway: OpcuaGateway, spy, url: str) -> None:
    async def body() -> None:
        c = Ua(url, USER, PASSWORD)
        await c.__aenter__()
        req = ua.CallMethodRequest(ObjectId=c.id("BaseStateMachine"), MethodId=c.id("BaseStateMachine/Reset"))
        task = asyncio.create_task(c.client.uaclient.call([req]))
        await asyncio.sleep(0)
        c.client.uaclient.protocol.transport.abort()  # the socket goes, no CloseSession
        with pytest.raises(BaseException):  # noqa: B017 - whatever the client library makes of a dead socket
            await asyncio.wait_for(task, 5)
        async with Ua(url, USER, PASSWORD) as c2:
            await asyncio.sleep(1.0)  # a request that got out has reached the daemon by now
            state = await c2.read("Status/StateCurrent")
            # the call reached the bus at most once, and the state agrees with what reached it
            assert spy.count in (0, 1)
            assert state in ((PackMLState.Stopped,) if spy.count == 0 else (PackMLState.Resetting, PackMLState.Idle))
            st, _ = await c2.call("Stop" if spy.count else "Reset")
            assert st.is_good()

    run(body())


def test_one_object_per_cell(cfg, daemon, tmp_path) -> None:
    from tests.gateway.conftest import make_gw_cfg

    gw_cfg = make_gw_cfg(tmp_path, "cells=[cell1, cell2]")
    with OpcuaGateway(cfg, gw_cfg).start_thread() as gw:
        wait_until(lambda: gw._down.get("cell1") is None, 20, "cell1's first Status")

        async def body() -> None:
            async with Ua(gw_cfg.endpoint, USER, PASSWORD) as c1, Ua(gw_cfg.endpoint, USER, PASSWORD, "cell2") as c2:
                assert await c1.read("Status/StateCurrent") == PackMLState.Stopped
                assert await c2.read("Status/StateCurrent") == PackMLState.Undefined
                assert await c2.read("Status/UnavailableReason") == "waiting for the daemon's first Status"
                for _ in range(100):
                    if "cell/cell2/status" in await c2.read("Status/UnavailableReason"):
                        break
                    await asyncio.sleep(0.05)
                assert "no Status from the daemon on 'cell/cell2/status'" in await c2.read("Status/UnavailableReason")
                st, reason = await c2.call("Reset")
                assert st.value == S.BadCommunicationError and "cell/cell2/cmd" in reason
                assert await c1.read("Status/StateCurrent") == PackMLState.Stopped

        run(body())
