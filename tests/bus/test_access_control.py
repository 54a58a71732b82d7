"""The secured bus on loopback: a real router with user/password auth and the generated ACL.

Refusals are asserted by ordering, not by waiting: an intruder's command is sent before the
PLC's, the supervisor handles commands in arrival order, so had the intruder's got through its
Ack would have reached the observer before the PLC's.
"""

from __future__ import annotations

import json
import queue
import shutil
import stat
import time
from pathlib import Path

import pytest
import zenoh

from cellctl.app import build_cell
from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.security import PRINCIPALS, access_control, init_deployment, rotate_password
from cellctl.bus.session import open_session
from cellctl.config import CellConfig, load_config
from cellctl.errors import ConfigError
from cellctl.messages import Ack, Command, CycleResult, Status
from tests.fakes.workers import FakeCell, fake_identify


@pytest.fixture(scope="module")
def deployment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("secure") / "cell1"
    init_deployment(out, "cell1")
    return out


def as_principal(cfg: CellConfig, principal: str | None, security_dir: Path) -> CellConfig:
    """``cfg`` on the secured bus of ``security_dir``, as client ``principal``."""
    bus = cfg.bus.model_copy(update={"security_dir": security_dir, "principal": principal})
    return cfg.model_copy(update={"bus": bus})


@pytest.fixture
def secured(cfg: CellConfig, deployment: Path):
    """A function: principal name → config of a client of the secured cell."""
    return lambda principal: as_principal(cfg, principal, deployment)


@pytest.fixture
def cell(cfg: CellConfig, deployment: Path):
    from cellctl.geometry.catalog import load_catalog

    router_cfg = as_principal(cfg, None, deployment)
    c = build_cell(router_cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    yield c
    c.close()


class Client:
    """One principal's session with a queue of the Acks and Statuses it is allowed to see."""

    def __init__(self, cfg: CellConfig) -> None:
        self.cfg = cfg
        self.s = open_session(cfg, "client")
        self.acks: queue.Queue[Ack] = queue.Queue()
        self.status: queue.Queue[Status] = queue.Queue()
        c = cfg.cell_id
        self.s.declare_subscriber(keys.cmd_ack(c), lambda x: self.acks.put(decode_as(Ack, x.payload.to_bytes())))
        self.s.declare_subscriber(keys.status(c), lambda x: self.status.put(decode_as(Status, x.payload.to_bytes())))
        time.sleep(0.2)  # let the subscriptions reach the router

    def put_cmd(self, command: str, request_id: str) -> None:
        self.s.put(keys.cmd(self.cfg.cell_id), encode(Command(command=command, request_id=request_id)))

    def query_cmd(self, command: str, request_id: str) -> list[zenoh.Reply]:
        msg = Command(command=command, request_id=request_id)
        return list(self.s.get(keys.cmd(self.cfg.cell_id), payload=encode(msg), timeout=5))

    def wait_state(self, state: str, timeout: float = 10.0) -> list[str]:
        """Every state seen until ``state``, inclusive."""
        seen: list[str] = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                seen.append(self.status.get(timeout=0.2).state)
            except queue.Empty:
                continue
            if seen[-1] == state:
                return seen
        raise AssertionError(f"state {state!r} not reached in {timeout} s; saw {seen}")

    def close(self) -> None:
        self.s.close()


def test_deployment_files_are_private_and_the_acl_follows_the_key_module(deployment: Path) -> None:
    assert stat.S_IMODE(deployment.stat().st_mode) == 0o700
    assert stat.S_IMODE((deployment / "passwords").stat().st_mode) == 0o600
    for p in PRINCIPALS:
        assert stat.S_IMODE((deployment / "clients" / f"{p}.json5").stat().st_mode) == 0o600
    entries = dict(line.split(":", 1) for line in (deployment / "passwords").read_text().splitlines())
    assert sorted(entries) == sorted(PRINCIPALS)
    assert len(set(entries.values())) == len(entries) and all(len(pw) >= 32 for pw in entries.values())
    router = zenoh.Config.from_file(str(deployment / "router.json5"))
    assert _without_nulls(json.loads(router.get_json("access_control"))) == access_control("cell1")
    # the bus.yaml snippet validates as a cell config
    cfg = load_config(None, [f"bus.{k}={v}" for k, v in _bus_section(deployment).items()])
    assert cfg.bus.security_dir == deployment.resolve() and cfg.bus.principal == "operator"


def _without_nulls(x):  # zenoh reports unset optional fields as null
    if isinstance(x, dict):
        return {k: _without_nulls(v) for k, v in x.items() if v is not None}
    return [_without_nulls(v) for v in x] if isinstance(x, list) else x


def _bus_section(deployment: Path) -> dict:
    import yaml

    return yaml.safe_load((deployment / "bus.yaml").read_text())["bus"]


def test_init_refuses_to_overwrite_secrets_without_force(deployment: Path) -> None:
    with pytest.raises(ConfigError, match="already holds a deployment"):
        init_deployment(deployment, "cell1")


def test_client_without_principal_or_with_unknown_one_is_a_config_error(secured) -> None:
    with pytest.raises(ConfigError, match="bus.principal is not set"):
        open_session(secured(None), "client")
    with pytest.raises(ConfigError, match=r"bus.principal 'intruder' has no credentials.*'plc'"):
        open_session(secured("intruder"), "client")


def test_wrong_password_cannot_connect(cfg, deployment: Path, tmp_path: Path, cell) -> None:
    stale = tmp_path / "stale"
    shutil.copytree(deployment, stale)
    rotate_password(stale, "plc")  # the copy's plc password is now one the router never saw
    with pytest.raises(ConfigError, match="reachable but refused principal 'plc'"):
        open_session(as_principal(cfg, "plc", stale), "client")
    with open_session(as_principal(cfg, "plc", deployment), "client") as s:
        assert s.info.routers_zid()  # the same router takes the right password


def test_only_the_plc_may_command(cell, secured) -> None:
    observer = Client(secured("operator"))
    intruders = [Client(secured(p)) for p in ("operator", "viewer", "robot", "engineer", "replay")]
    plc = Client(secured("plc"))
    try:
        for i, intruder in enumerate(intruders):
            intruder.put_cmd("reset", f"intruder-put-{i}")
            assert intruder.query_cmd("reset", f"intruder-query-{i}") == []  # refused: no reply at all
        plc.put_cmd("reset", "plc-put")
        ack = observer.acks.get(timeout=5)
        assert (ack.request_id, ack.accepted) == ("plc-put", True)
        observer.wait_state("Idle")
        assert observer.acks.empty()
        (reply,) = plc.query_cmd("stop", "plc-query")
        assert decode_as(Ack, reply.ok.payload.to_bytes()).accepted
        observer.wait_state("Stopped")
    finally:
        for c in (observer, *intruders, plc):
            c.close()


def test_status_is_readable_by_all_but_acks_only_by_observers(cell, secured) -> None:
    viewer, operator, plc = Client(secured("viewer")), Client(secured("operator")), Client(secured("plc"))
    try:
        for c in (viewer, operator):
            (reply,) = list(c.s.get(keys.status("cell1"), timeout=5))
            assert decode_as(Status, reply.ok.payload.to_bytes()).state == "Stopped"
        plc.put_cmd("reset", "r1")
        viewer.wait_state("Idle")
        assert operator.acks.get(timeout=5).request_id == "r1"
        assert viewer.acks.empty()  # it saw the state change the Ack announced, never the Ack
        # nobody but the supervisor may publish status: a forged one never reaches the viewer
        forged = Status(cell="cell1", state="Forged", state_code=99, available_commands=[])
        plc.s.put(keys.status("cell1"), encode(forged))
        plc.put_cmd("stop", "r2")
        assert operator.acks.get(timeout=5).request_id == "r2"
        assert "Forged" not in viewer.wait_state("Stopped")
    finally:
        for c in (viewer, operator, plc):
            c.close()


def test_a_worker_serves_only_its_own_keys(cell, secured) -> None:
    c = "cell1"
    with open_session(secured("camera"), "client") as cam:
        cam.declare_queryable(keys.robot_op(c, "move"), lambda q: q.reply(q.key_expr, b"forged move"))
        cam.declare_queryable(keys.camera_capture(c), lambda q: q.reply(q.key_expr, b"capture"))
        tokens = [cam.liveliness().declare_token(keys.alive(c, r)) for r in ("robot", "camera")]  # noqa: F841 - a dropped token is undeclared
        time.sleep(0.3)
        router = cell.session
        assert list(router.get(keys.robot_op(c, "move"), timeout=2)) == []  # as if no robot were there
        (reply,) = router.get(keys.camera_capture(c), timeout=2)
        assert reply.ok.payload.to_bytes() == b"capture"
        (reply,) = router.get(keys.status(c), timeout=2)
        workers = decode_as(Status, reply.ok.payload.to_bytes()).workers
        assert workers.get("camera") is True and not workers.get("robot")
        # nor may one worker query another's ops
        assert list(cam.get(keys.robot_op(c, "stop"), timeout=2)) == []


def test_a_workers_declared_publisher_reaches_observers(cell, secured) -> None:
    # a client that declared a publisher sends only to subscribers the router told it about,
    # so the ACL must let subscriber declarations out to the publishing worker
    with open_session(secured("robot"), "client") as rob, open_session(secured("operator"), "client") as op:
        pub = rob.declare_publisher(keys.robot_joints("cell1"))
        got: queue.Queue[bytes] = queue.Queue()
        op.declare_subscriber(keys.robot_joints("cell1"), lambda x: got.put(x.payload.to_bytes()))
        time.sleep(0.3)
        pub.put(b"joints")
        assert got.get(timeout=5) == b"joints"


def test_a_worker_sees_the_supervisor_come_and_go(cfg, deployment: Path, secured) -> None:
    # the robot worker stops its motion on the DELETE of this token (workers/robot)
    router = open_session(as_principal(cfg, None, deployment), "router")
    router_token = router.liveliness().declare_token(keys.alive("cell1", "supervisor"))
    with open_session(secured("robot"), "client") as rob:
        seen: queue.Queue[zenoh.SampleKind] = queue.Queue()
        rob.liveliness().declare_subscriber(keys.alive("cell1", "supervisor"), lambda x: seen.put(x.kind), history=True)
        assert seen.get(timeout=5) == zenoh.SampleKind.PUT
        router_token.undeclare()
        assert seen.get(timeout=5) == zenoh.SampleKind.DELETE
    router.close()


def test_engineer_may_query_worker_ops_operator_may_not(cell, secured) -> None:
    c = "cell1"
    with open_session(secured("robot"), "client") as rob:
        rob.declare_queryable(keys.robot_op(c, "state"), lambda q: q.reply(q.key_expr, b"joints"))
        time.sleep(0.3)
        with open_session(secured("operator"), "client") as op:
            assert list(op.get(keys.robot_op(c, "state"), timeout=2)) == []
        with open_session(secured("engineer"), "client") as eng:
            (reply,) = eng.get(keys.robot_op(c, "state"), timeout=2)
            assert reply.ok.payload.to_bytes() == b"joints"


def test_full_cycle_with_every_worker_under_its_own_principal(cell, secured) -> None:
    fakes = [FakeCell(secured(role), roles=(role,)).start() for role in keys.ROLES]
    plc = Client(secured("plc"))
    results: queue.Queue[CycleResult] = queue.Queue()
    plc.s.declare_subscriber(keys.result("cell1"), lambda x: results.put(decode_as(CycleResult, x.payload.to_bytes())))
    try:
        assert decode_as(Ack, plc.query_cmd("reset", "r")[0].ok.payload.to_bytes()).accepted
        plc.wait_state("Idle")
        assert decode_as(Ack, plc.query_cmd("start", "s")[0].ok.payload.to_bytes()).accepted
        plc.wait_state("Complete")
        assert results.get(timeout=5).outcome == "completed"
    finally:
        plc.close()
        for f in fakes:
            f.close()


@pytest.fixture(scope="module")
def mtls_deployment(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("secure-mtls") / "cell1"
    init_deployment(out, "cell1", mtls=True)
    return out


def test_mtls_binds_the_password_to_the_certificate(cfg, mtls_deployment: Path, tmp_path: Path) -> None:
    ep = cfg.bus.listen[0].replace("tcp/", "tls/")
    tls_cfg = cfg.model_copy(update={"bus": cfg.bus.model_copy(update={"listen": [ep], "connect": [ep]})})
    with build_cell(as_principal(tls_cfg, None, mtls_deployment), identification=(fake_identify, None)):
        plc = Client(as_principal(tls_cfg, "plc", mtls_deployment))
        try:
            # plc's password with the robot's certificate: the link is up (our CA signed it) but the
            # ACL subject wants user plc AND certificate CN plc, so the command is dropped
            borrowed = tmp_path / "borrowed"
            shutil.copytree(mtls_deployment, borrowed)
            client = borrowed / "clients" / "plc.json5"
            client.write_text(client.read_text().replace("tls/plc.", "tls/robot."))
            thief = Client(as_principal(tls_cfg, "plc", borrowed))
            assert thief.query_cmd("reset", "thief") == []
            thief.close()
            (reply,) = plc.query_cmd("reset", "plc")
            assert decode_as(Ack, reply.ok.payload.to_bytes()).accepted
            # without a client certificate the router refuses the link itself
            client.write_text(
                "\n".join(
                    line for line in client.read_text().splitlines() if "connect_" not in line and "mtls" not in line
                )
            )
            with pytest.raises(ConfigError, match="refused principal 'plc'"):
                open_session(as_principal(tls_cfg, "plc", borrowed), "client")
        finally:
            plc.close()


def test_cli_init_then_cmd_as_the_wrong_and_the_right_principal(cell, port: int, tmp_path: Path, capsys) -> None:
    from cellctl.cli import main

    assert main(["secure", "init", "--out", str(tmp_path / "dep")]) == 0
    out = capsys.readouterr().out
    assert f"-rw-------  {tmp_path / 'dep' / 'passwords'}" in out and "bus.security_dir=" in out
    # the running cell uses the module's deployment; the CLI is pointed at the same one
    ep = f'["tcp/127.0.0.1:{port}"]'
    base = ["cmd", "reset", "--timeout", "2", "--set", f"bus.listen={ep}", "--set", f"bus.connect={ep}"]
    base += ["--set", f"bus.security_dir={cell.cfg.bus.security_dir}"]
    assert main([*base, "--set", "bus.principal=operator"]) == 2
    assert "access-control list refuses 'cell/cell1/cmd' to principal 'operator'" in capsys.readouterr().err
    assert cell.supervisor.top_state == "Stopped"
    assert main([*base, "--set", "bus.principal=plc", "--wait", "Idle"]) == 0
    assert '"reached": "Idle"' in capsys.readouterr().out
