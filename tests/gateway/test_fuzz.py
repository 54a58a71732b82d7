"""Seeded hostile writes and calls against the gateway (real daemon, no workers).

Every case is checked against two views the gateway does not control: the spy counts what reached
the bus, and the daemon's own Status (by Zenoh query) says whether the state moved. A request the
gateway refuses must not reach the bus; a request that reached the bus and was refused must not move
the state; the gateway must answer every case and keep serving.
"""

from __future__ import annotations

import asyncio
import logging
import random
import time

import pytest
from asyncua import ua

from cellctl.bus.plc_client import PlcClient
from cellctl.gateway.opcua import OpcuaGateway
from tests.gateway.conftest import PASSWORD, USER, Ua

V = ua.VariantType
S = ua.StatusCodes
WAIT_STATES = {"Stopped", "Idle", "Aborted", "Held", "Suspended", "Complete"}
LOCAL_REFUSALS = {
    S.BadOutOfRange,
    S.BadTypeMismatch,
    S.BadNothingToDo,
    S.BadUserAccessDenied,
    S.BadTooManyArguments,
    S.BadArgumentsMissing,
    S.BadMethodInvalid,
    S.BadNodeIdUnknown,
    S.BadNodeIdInvalid,
    S.BadIndexRangeInvalid,
    S.BadAttributeIdInvalid,
    S.BadNotWritable,
    S.BadWriteNotSupported,
    S.BadNothingToDo,
}
WRITABLE = [
    "Command/CntrlCmd",
    "Command/CmdChangeRequest",
    "Command/UnitMode",
    "Command/UnitModeChangeRequest",
    "Command/Parameter/Mode",
    "Command/Parameter/Surface",
    "Command/Parameter/Label",
]
READ_ONLY = ["Status/StateCurrent", "Admin/ProdProcessedCount", "Status/CmdAccepted", "Admin/Warning"]
METHODS = ["Reset", "Start", "Stop", "Hold", "Unhold", "Suspend", "Unsuspend", "Abort", "Clear", "ToComplete"]


def hostile_value(rng: random.Random) -> ua.Variant:
    kind = rng.randrange(12)
    if kind < 4:
        return ua.Variant(
            rng.choice([0, 1, 2, 3, 8, 9, 10, 11, -1, 2**31 - 1, -(2**31), rng.randint(-99, 99)]), V.Int32
        )
    if kind == 4:
        return ua.Variant(rng.random() < 0.5, V.Boolean)
    if kind == 5:
        return ua.Variant(rng.choice([1.0, float("nan"), -0.0, 1e300]), V.Double)
    if kind == 6:
        return ua.Variant(
            rng.choice(["", "1", "evaluate", "collect", "dirty", "x" * 5000, "\u0000\ufffd", "internal"]), V.String
        )
    if kind == 7:
        vtype = rng.choice([V.Int16, V.Int64, V.UInt32, V.Byte, V.SByte])
        return ua.Variant(rng.randint(0 if vtype in (V.UInt32, V.Byte) else -5, 12), vtype)
    if kind == 8:
        return ua.Variant([rng.randint(0, 11) for _ in range(rng.randint(0, 4))], V.Int32)
    if kind == 9:
        return ua.Variant(bytes(rng.randrange(256) for _ in range(rng.randint(0, 64))), V.ByteString)
    if kind == 10:
        return ua.Variant(None, V.Null)
    return ua.Variant(ua.LocalizedText("Idle"), V.LocalizedText)


REQUESTS = ("Command/CmdChangeRequest", "Command/UnitModeChangeRequest")


def _is_request(client: Ua, wv: ua.WriteValue) -> bool:
    """A write the gateway turns into a Command unless it refuses it: a change request set to true."""
    v = wv.Value.Value
    return (
        wv.NodeId in {client.id(p) for p in REQUESTS}
        and wv.AttributeId == ua.AttributeIds.Value
        and not wv.IndexRange
        and v.VariantType == V.Boolean
        and v.Value is True
    )


async def one_case(rng: random.Random, c: Ua, anon: Ua) -> tuple[str, list[int]]:
    """Do one hostile operation; return its description and the status of each part that may become a Command."""
    kind = rng.randrange(10)
    client = anon if rng.random() < 0.08 else c
    try:
        if kind <= 4:  # writes, often a CntrlCmd followed by a change request in the same request
            nodes = []
            for _ in range(rng.randint(1, 3)):
                path = rng.choice(WRITABLE + READ_ONLY) if rng.random() < 0.9 else "Status/NoSuchTag"
                value = hostile_value(rng)
                if rng.random() < 0.3 and path == "Command/CntrlCmd":
                    value = ua.Variant(rng.randint(1, 10), V.Int32)
                wv = ua.WriteValue(NodeId=client.id(path), AttributeId=ua.AttributeIds.Value, Value=ua.DataValue(value))
                if rng.random() < 0.05:
                    wv.IndexRange = "0:1"
                if rng.random() < 0.05:
                    wv.AttributeId = ua.AttributeIds.DisplayName
                nodes.append(wv)
            if rng.random() < 0.3:
                nodes.append(
                    ua.WriteValue(
                        NodeId=client.id(rng.choice(REQUESTS)),
                        AttributeId=ua.AttributeIds.Value,
                        Value=ua.DataValue(ua.Variant(True, V.Boolean)),
                    )
                )
            params = ua.WriteParameters()
            params.NodesToWrite = nodes
            results = await client.client.uaclient.write(params)
            codes = [r.value for wv, r in zip(nodes, results, strict=True) if _is_request(client, wv)]
            return f"write {[(str(n.NodeId.Identifier), n.Value.Value.VariantType.name) for n in nodes]}", codes
        name = rng.choice([*METHODS, "SetUnitMode"])
        parent = "" if name == "SetUnitMode" else "BaseStateMachine"
        args = [hostile_value(rng) for _ in range(rng.choice([0, 0, 0, 1, 1, 2]))]
        if name == "SetUnitMode" and rng.random() < 0.5:
            args = [ua.Variant(rng.randint(0, 4), V.Int32)]
        obj = client.id(parent) if parent else ua.NodeId(client.cell, client.ns)
        if rng.random() < 0.05:
            obj = client.id("Admin")
        req = ua.CallMethodRequest(
            ObjectId=obj, MethodId=client.id(f"{parent}/{name}" if parent else name), InputArguments=args
        )
        res = (await client.client.uaclient.call([req]))[0]
        return f"call {name}({[a.VariantType.name for a in args]})", [res.StatusCode.value]
    except ua.UaStatusCodeError as err:  # a whole service refused (anonymous Write/Call)
        return f"service refused {kind}", [err.code]


def fuzz(gateway: OpcuaGateway, spy, cfg, url: str, n: int, seed: int) -> dict:
    rng = random.Random(seed)
    stats = {"cases": 0, "forwarded": 0, "refused_locally": 0, "accepted": 0, "refused_by_daemon": 0}

    async def body() -> None:
        with PlcClient(cfg, "fuzz-view") as view:
            async with Ua(url, USER, PASSWORD) as c, Ua(url) as anon:
                for i in range(n):
                    before_state = view.status().state
                    before_count = spy.count
                    what, codes = await one_case(rng, c, anon)
                    where = f"case {i} (seed {seed}) {what} -> {[ua.StatusCode(x).name for x in codes]}"
                    forwarded = spy.count - before_count
                    expected = sum(1 for x in codes if x not in LOCAL_REFUSALS)
                    assert forwarded == expected, f"{where}: {forwarded} commands on the bus, expected {expected}"
                    stats["cases"] += 1
                    stats["forwarded"] += forwarded
                    stats["refused_locally"] += len(codes) - expected
                    accepted = sum(1 for x in codes if x == S.Good)
                    stats["accepted"] += accepted
                    stats["refused_by_daemon"] += expected - accepted
                    if accepted:
                        deadline = time.monotonic() + 10
                        while view.status().state not in WAIT_STATES and time.monotonic() < deadline:
                            await asyncio.sleep(0.02)
                    elif before_state in WAIT_STATES:
                        after = view.status().state
                        assert after == before_state, f"{where}: refused, but the state moved {before_state} -> {after}"
                # still serving: a plain read and a plain command work
                assert await c.read("Status/StateName") == view.status().state
                assert (await c.call("Abort" if view.status().state != "Aborted" else "Clear"))[0].is_good()

    asyncio.run(body())
    assert gateway.error is None and gateway._thread is not None and gateway._thread.is_alive()
    assert spy.count == gateway.commands_sent
    return stats


def _no_hook_failures(caplog: pytest.LogCaptureFixture) -> None:
    failures = [r for r in caplog.records if r.name.startswith("cellctl.gateway") and r.levelno >= logging.ERROR]
    assert not failures, failures[0].getMessage()


def test_fuzz_2000_hostile_writes_and_calls(gateway, spy, cfg, url, caplog) -> None:
    """~10 s on two shared cores, so the whole 2000 cases run in the default suite."""
    caplog.set_level(logging.ERROR, logger="cellctl.gateway")
    stats = fuzz(gateway, spy, cfg, url, 2000, seed=2026)
    print("fuzz 2000 seed 2026:", stats)
    _no_hook_failures(caplog)
    assert stats["cases"] == 2000 and stats["accepted"] > 20 and stats["refused_by_daemon"] > 100, stats
    assert stats["refused_locally"] > 300, stats
