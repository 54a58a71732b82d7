"""The HMI on the secured bus: it connects as its own principal ``hmi``, which may command and read
but may not serve a worker key (cellctl.bus.security)."""

from __future__ import annotations

import pytest

from cellctl.app import build_cell
from cellctl.bus import keys
from cellctl.bus.security import PRINCIPALS, access_control, init_deployment
from cellctl.hmi.server import Hmi, HmiServer
from tests.fakes.workers import fake_identify
from tests.hmi.conftest import Client, hmi_config, wait_reachable


def _granted(acl: dict, principal: str) -> list[dict]:
    rules = {r["id"]: r for r in acl["rules"]}
    (policy,) = [p for p in acl["policies"] if p["id"] == principal]
    return [rules[r] for r in policy["rules"]]


def test_the_hmi_principal_may_command_and_read_but_serves_no_worker_key() -> None:
    assert "hmi" in PRINCIPALS
    rules = _granted(access_control("cell1"), "hmi")
    ingress = {(m, k) for r in rules if "ingress" in r["flows"] for m in r["messages"] for k in r["key_exprs"]}
    assert ("query", keys.cmd("cell1")) in ingress
    assert ("declare_subscriber", keys.status("cell1")) in ingress
    assert not any(m == "declare_queryable" for m, _ in ingress)
    for role in keys.ROLES:
        serving = {(m, k) for m, k in ingress if k.startswith(f"cell/cell1/{role}/") and m in ("reply", "put")}
        assert not serving, (role, serving)


def test_the_hmi_commands_a_secured_cell_as_principal_hmi(cfg, tmp_path, clock) -> None:
    from cellctl.geometry.catalog import load_catalog

    sec = tmp_path / "secure"
    init_deployment(sec, cfg.cell_id, endpoint=cfg.bus.listen[0].split("/", 1)[1])
    router = cfg.model_copy(update={"bus": cfg.bus.model_copy(update={"security_dir": sec})})
    hmi_cfg = cfg.model_copy(update={"bus": cfg.bus.model_copy(update={"security_dir": sec, "principal": "hmi"})})
    cell = build_cell(router, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    h = Hmi(hmi_cfg, hmi_config(), clock)
    server = HmiServer(h).start()
    try:
        c = Client(h.hcfg.host, h.hcfg.port)
        wait_reachable(c, 20)
        c.login("alice")
        r = c.cmd("reset")
        assert r.status == 200 and r.json()["ack"]["user"] == "hmi:alice", r.body
        c.wait_state("Idle")
    finally:
        server.stop()
        h.close()
        cell.close()


@pytest.mark.parametrize("principal", ["viewer"])
def test_a_principal_without_the_command_grant_gets_no_ack(cfg, tmp_path, clock, principal: str) -> None:
    from cellctl.geometry.catalog import load_catalog

    sec = tmp_path / "secure"
    init_deployment(sec, cfg.cell_id, endpoint=cfg.bus.listen[0].split("/", 1)[1])
    router = cfg.model_copy(update={"bus": cfg.bus.model_copy(update={"security_dir": sec})})
    other = cfg.model_copy(update={"bus": cfg.bus.model_copy(update={"security_dir": sec, "principal": principal})})
    cell = build_cell(router, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    h = Hmi(other, hmi_config(command_timeout_s=1.0), clock)
    server = HmiServer(h).start()
    try:
        c = Client(h.hcfg.host, h.hcfg.port)
        wait_reachable(c, 20)  # a viewer may read the status
        c.login("alice")
        r = c.cmd("reset")
        assert r.status in (503, 504) and cell.supervisor.top_state == "Stopped", r.body
    finally:
        server.stop()
        h.close()
        cell.close()
