"""A real daemon (worker doubles over real Zenoh), the OPC UA gateway on a loopback port, a command spy."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from asyncua import Client, ua

from cellctl.app import build_cell
from cellctl.bus import keys
from cellctl.bus.codec import encode
from cellctl.bus.plc_client import PlcClient
from cellctl.bus.session import open_session
from cellctl.config import CellConfig, load_config
from cellctl.gateway.opcua import CELLCTL_NS, OpcuaConfig, OpcuaGateway, load_gateway_config
from cellctl.messages import Command
from tests.conftest import cfg_overrides, free_port
from tests.fakes.workers import fake_identify

USER, PASSWORD = "line-plc", "line-plc-password-1"


def wait_until(pred: Callable[[], Any], timeout: float = 10.0, what: str = "condition") -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = pred()
        if v:
            return v
        time.sleep(0.02)
    raise AssertionError(f"{what} not reached within {timeout} s")


class CommandSpy:
    """Sees every query on the cell's cmd key (a second queryable that never replies), so tests count
    exactly what the gateway put on the bus."""

    def __init__(self, cfg: CellConfig) -> None:
        self.session = open_session(cfg, "client")
        self.payloads: list[bytes] = []
        self._lock = threading.Lock()

        def seen(q: zenoh.Query) -> None:
            with self._lock:
                self.payloads.append(q.payload.to_bytes() if q.payload is not None else b"")
            q.drop()

        self._q = self.session.declare_queryable(keys.cmd(cfg.cell_id), seen)
        time.sleep(0.2)  # let the declaration reach the router

    @property
    def count(self) -> int:
        with self._lock:
            return len(self.payloads)

    def close(self) -> None:
        self._q.undeclare()
        self.session.close()


def make_daemon(cfg: CellConfig) -> Any:
    from cellctl.geometry.catalog import load_catalog

    return build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))


@pytest.fixture(scope="module")
def shared_cfg(tmp_path_factory: pytest.TempPathFactory) -> CellConfig:
    """One daemon and gateway per test module: asyncua's server takes seconds to build its standard address space."""
    tmp = tmp_path_factory.mktemp("gw")
    return load_config(None, cfg_overrides(tmp, free_port()))


@pytest.fixture(scope="module")
def shared_gw_cfg(tmp_path_factory: pytest.TempPathFactory) -> OpcuaConfig:
    return make_gw_cfg(tmp_path_factory.mktemp("gw-users"))


@pytest.fixture(scope="module")
def shared_cell(shared_cfg: CellConfig, shared_gw_cfg: OpcuaConfig) -> Iterator[tuple[Any, OpcuaGateway]]:
    c = make_daemon(shared_cfg)
    gw = OpcuaGateway(shared_cfg, shared_gw_cfg).start_thread()
    try:
        wait_until(lambda: gw._down.get(shared_cfg.cell_id) is None, 20, "the gateway's first Status")
        yield c, gw
    finally:
        gw.close()
        c.close()


@pytest.fixture
def cfg(shared_cfg: CellConfig) -> CellConfig:  # the module's cell, for FakeCell and the spy
    return shared_cfg


@pytest.fixture
def daemon(shared_cell: tuple[Any, OpcuaGateway]) -> Any:
    return shared_cell[0]


@pytest.fixture
def gw_cfg(shared_gw_cfg: OpcuaConfig) -> OpcuaConfig:
    return shared_gw_cfg


@pytest.fixture
def gateway(shared_cfg: CellConfig, shared_cell: tuple[Any, OpcuaGateway]) -> OpcuaGateway:
    """The module's gateway, with the cell brought back to Stopped in Production and the tags cleared."""
    cell, gw = shared_cell
    with PlcClient(shared_cfg, "gw-test-setup") as plc:
        st = plc.status()
        if st.state not in ("Stopped", "Aborted"):
            plc.command("abort")
            wait_until(lambda: plc.status().state == "Aborted", 10, "Aborted")
        if plc.status().state == "Aborted":
            plc.command("clear")
            wait_until(lambda: plc.status().state == "Stopped", 10, "Stopped")
        if plc.status().unit_mode != "production":
            plc.session.get(keys.cmd(shared_cfg.cell_id), payload=encode(Command(unit_mode="production")), timeout=5)
    wait_until(lambda: gw._values.get(gw._spaces["cell1"].nodeid("Status/StateName")) == "Stopped", 10)
    gw.commands_sent = 0
    return gw


def make_gw_cfg(folder: Path, *extra: str) -> OpcuaConfig:
    users = folder / "opcua-users"
    users.write_text(f"# who may command\n{USER}:{PASSWORD}\n")
    return load_gateway_config(
        None, [f"endpoint=opc.tcp://127.0.0.1:{free_port()}", f"users_file={users}", "stale_after_s=1.5", *extra]
    )


@pytest.fixture
def spy(cfg: CellConfig, daemon: Any) -> Iterator[CommandSpy]:
    s = CommandSpy(cfg)
    yield s
    s.close()


class Ua:
    """An asyncua client session with the gateway's node ids at hand (tests run it with asyncio.run)."""

    def __init__(self, url: str, user: str | None = None, password: str | None = None, cell: str = "cell1") -> None:
        self.client = Client(url, timeout=10)
        if user is not None:
            self.client.set_user(user)
            self.client.set_password(password or "")
        self.cell = cell
        self.ns = 0

    async def __aenter__(self) -> Ua:
        await self.client.connect()
        self.ns = await self.client.get_namespace_index(CELLCTL_NS)
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.client.disconnect()

    def id(self, path: str) -> ua.NodeId:
        return ua.NodeId(f"{self.cell}/{path}", self.ns)

    async def read(self, path: str) -> Any:
        return await self.client.get_node(self.id(path)).read_value()

    async def write(self, path: str, value: Any, vtype: ua.VariantType) -> ua.StatusCode:
        """Write one value and return the per-node status (Bad codes are returned, not raised)."""
        params = ua.WriteParameters()
        params.NodesToWrite = [
            ua.WriteValue(
                NodeId=self.id(path), AttributeId=ua.AttributeIds.Value, Value=ua.DataValue(ua.Variant(value, vtype))
            )
        ]
        return (await self.client.uaclient.write(params))[0]

    async def call(self, name: str, *args: ua.Variant, parent: str = "BaseStateMachine") -> tuple[ua.StatusCode, str]:
        """Call a method; return its status and the Reason output ('' when accepted)."""
        req = ua.CallMethodRequest(
            ObjectId=self.id(parent) if parent else ua.NodeId(self.cell, self.ns),
            MethodId=self.id(f"{parent}/{name}" if parent else name),
            InputArguments=list(args),
        )
        res = (await self.client.uaclient.call([req]))[0]
        out = res.OutputArguments[0].Value if res.OutputArguments else ""
        return res.StatusCode, out

    async def handshake(self, cntrl_cmd: int) -> ua.StatusCode:
        """PackTags: CntrlCmd, then CmdChangeRequest; returns the CmdChangeRequest write's status."""
        st = await self.write("Command/CntrlCmd", cntrl_cmd, ua.VariantType.Int32)
        assert st.is_good(), st
        return await self.write("Command/CmdChangeRequest", True, ua.VariantType.Boolean)

    async def wait_value(self, path: str, want: Any, timeout: float = 10.0) -> Any:
        deadline = time.monotonic() + timeout
        v = None
        while time.monotonic() < deadline:
            v = await self.read(path)
            if v == want:
                return v
            await asyncio.sleep(0.02)
        raise AssertionError(f"{path} is {v!r}, not {want!r} after {timeout} s")


@pytest.fixture
def url(gw_cfg: OpcuaConfig) -> str:
    return gw_cfg.endpoint


@pytest.fixture
def own_cfgs(tmp_path: Path) -> tuple[CellConfig, OpcuaConfig]:
    """A private bus port and gateway endpoint, for tests that start and stop their own daemon."""
    return load_config(None, cfg_overrides(tmp_path, free_port())), make_gw_cfg(tmp_path)
