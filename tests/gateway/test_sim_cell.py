"""node-opcua through the gateway against the whole sim cell (pybullet twin, real workers): slow, `make test-all`."""

from __future__ import annotations

import pytest

from cellctl.bench.options import BenchOptions
from cellctl.bus.session import private_bus_overrides
from cellctl.gateway.opcua import OpcuaGateway
from tests.gateway.conftest import make_gw_cfg, wait_until
from tests.gateway.test_node_opcua import NODE, node_plc

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(NODE is None, reason="node (Node.js) is not on PATH: the node-opcua tests need it"),
]

# motions x1000, small frames, and a small plan (p_SP 2 %) so that priming the plan cache stays short
QUICK = ["planner.seed_pct=2"]


def test_node_opcua_runs_a_sim_cycle(tmp_path) -> None:
    from cellctl.bench.reliability.sim_cell import FAST_SIM, running_sim_cell

    opts = BenchOptions(overrides=(*private_bus_overrides(), *QUICK))
    with running_sim_cell(opts, "opcua-sim", FAST_SIM) as run:
        gw_cfg = make_gw_cfg(tmp_path)
        with OpcuaGateway(run.cfg, gw_cfg).start_thread() as gw:
            wait_until(lambda: gw._down.get(run.cfg.cell_id) is None, 20, "the gateway's first Status")
            runs = node_plc(gw_cfg.endpoint, "browse,handshake,methods", "line-plc", "line-plc-password-1", timeout=900)
    assert "BadUserAccessDenied" in runs["browse"]["write_cntrl_cmd"]
    assert [s["change_request"] for s in runs["handshake"]["steps"]] == ["Good", "Good"]
    assert [s["status"] for s in runs["methods"]["steps"]] == ["Good", "Good"]
    for how in ("handshake", "methods"):
        out = runs[how]
        assert out["processed_after"] == out["processed_before"] + 1, how
        assert out["last_outcome"] == "completed", how
        assert 6 in out["states_seen"] and out["states_seen"][-1] == 17, how
