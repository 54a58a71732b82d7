"""The per-host router configs: typed, unknown keys refused, the examples in config/deploy/ valid."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cellctl.bus.router import effective_config, load_router_config, router_zenoh_config
from cellctl.config import CellConfig, project_root, safe_yaml_load
from cellctl.errors import ConfigError

DEPLOY = project_root() / "config" / "deploy"


@pytest.mark.parametrize("path", sorted(DEPLOY.glob("*.router.yaml")), ids=lambda p: p.name)
def test_every_example_router_config_loads_with_scouting_off(path: Path) -> None:
    rc = load_router_config(path)
    eff = effective_config(router_zenoh_config(rc))
    assert eff["mode"] == "router"
    assert eff["scouting/multicast/enabled"] is False
    assert eff["transport/link/tx/lease"] == rc.lease_ms
    assert eff["connect/endpoints"] == rc.connect


def test_the_reference_plant_is_three_cells_a_compute_and_a_plant_host() -> None:
    hosts = {load_router_config(p).host: load_router_config(p) for p in DEPLOY.glob("*.router.yaml")}
    assert sorted(hosts) == ["cell1", "cell2", "cell3", "compute", "plant"]
    assert hosts["compute"].pool is not None and hosts["compute"].pool.cells == ["cell1", "cell2", "cell3"]
    for c in ("cell1", "cell2", "cell3"):  # each cell host dials its daemon, the compute and the plant host
        assert len(hosts[c].connect) == 3 and hosts[c].pool is None


@pytest.mark.parametrize(
    "path", sorted(set(DEPLOY.glob("*.yaml")) - set(DEPLOY.glob("*.router.yaml"))), ids=lambda p: p.name
)
def test_every_example_cell_config_validates(path: Path) -> None:
    data = safe_yaml_load(path.read_text(), str(path))
    cfg = CellConfig.model_validate({**data, "root": project_root()})
    assert cfg.bus.multicast_scouting is False


def _write(tmp: Path, body: dict) -> Path:
    p = tmp / "host.yaml"
    p.write_text(json.dumps(body))
    return p


def test_unknown_key_and_bad_endpoint_are_refused_by_name(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"unknown key 'listn'; allowed keys here: \['connect', 'host'"):
        load_router_config(_write(tmp_path, {"host": "a", "listn": ["tcp/127.0.0.1:7447"]}))
    with pytest.raises(ConfigError, match=r"endpoint '127.0.0.1:7447' is invalid"):
        load_router_config(_write(tmp_path, {"host": "a", "listen": ["127.0.0.1:7447"]}))
    with pytest.raises(ConfigError, match=r"cells \['cell1', 'cell1'\] name a cell twice"):
        load_router_config(
            _write(
                tmp_path,
                {"host": "a", "listen": ["tcp/127.0.0.1:7447"], "pool": {"cells": ["cell1", "cell1"], "jobs_dir": "j"}},
            )
        )
    with pytest.raises(ConfigError, match="does not exist"):
        load_router_config(tmp_path / "missing.yaml")


def test_pool_jobs_dir_resolves_against_the_file(tmp_path: Path) -> None:
    rc = load_router_config(
        _write(
            tmp_path,
            {"host": "compute", "listen": ["tcp/127.0.0.1:7447"], "pool": {"cells": ["cell1"], "jobs_dir": "jobs"}},
        )
    )
    assert rc.pool is not None and rc.pool.jobs_dir == tmp_path.resolve() / "jobs"


def test_cellctl_router_check_prints_the_effective_settings() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "cellctl", "router", str(DEPLOY / "compute.router.yaml"), "--check"],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    eff = json.loads(out.stdout)
    assert eff["host"] == "compute" and "tcp/compute.line.example:7447" in eff["listen/endpoints"]


def test_pool_keys_are_valid_and_match_every_cell() -> None:
    import zenoh

    from cellctl.bus import keys

    for k in (
        keys.planner_jobs_any(),
        keys.planner_lookup_any(),
        keys.pool_claim(),
        keys.pool_done(),
        keys.pool_stats(),
        keys.pool_alive(),
        keys.pool_alive("p12-ab"),
    ):
        assert str(zenoh.KeyExpr(k)) == k
    assert zenoh.KeyExpr(keys.planner_jobs_any()).includes(zenoh.KeyExpr(keys.planner_jobs("cell7")))
    assert zenoh.KeyExpr(keys.planner_lookup_any()).includes(zenoh.KeyExpr(keys.worker_op("c-2", "planner", "lookup")))
    assert not zenoh.KeyExpr(keys.planner_jobs_any()).includes(zenoh.KeyExpr(keys.planner_job_progress("cell1", "j")))
    assert keys.cell_from_key("cell/cell3/planner/jobs") == "cell3"
    with pytest.raises(ConfigError, match="is not a cell key"):
        keys.cell_from_key("pool/planner/claim")
    with pytest.raises(ConfigError, match="instance name 'P!' is invalid"):
        keys.pool_alive("P!")
