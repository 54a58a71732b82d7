"""The gateway driven by node-opcua, an OPC UA stack written independently of asyncua.

The client script is tests/gateway/node/plc.js; node-opcua-client is installed by `make test` into the
git-ignored .node/ folder. Skipped only when `node` is not on PATH. One node process runs every scenario
in order (loading node-opcua takes seconds), each in its own session; the tests below read its results.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from cellctl.config import project_root
from tests.fakes.workers import FakeCell
from tests.gateway.conftest import PASSWORD, USER, CommandSpy, wait_until

NODE = shutil.which("node")
SCRIPT = Path(__file__).parent / "node" / "plc.js"
NODE_DIR = project_root() / ".node"
SCENARIOS = ("browse", "bad-input", "handshake", "methods")

pytestmark = pytest.mark.skipif(NODE is None, reason="node (Node.js) is not on PATH: the node-opcua tests need it")


def node_plc(url: str, scenarios: str, *login: str, timeout: float = 120) -> dict[str, Any]:
    """Run plc.js; ``timeout`` (s) bounds the process and each wait for Complete."""
    if not (NODE_DIR / "node_modules" / "node-opcua-client").is_dir():
        pytest.fail("node-opcua-client is not installed in .node/: run `make node-deps` (make test does it)")
    env = {
        **os.environ,
        "NODE_PATH": str(NODE_DIR / "node_modules"),
        # node-opcua keeps its client certificate (made on first use) under the config home: keep it in .node/
        "XDG_CONFIG_HOME": str(NODE_DIR / "config"),
        "PLC_CYCLE_TIMEOUT_MS": str(int(timeout * 1000 * 0.8)),
    }
    proc = subprocess.run(
        [NODE, str(SCRIPT), url, scenarios, *login], capture_output=True, text=True, timeout=timeout, env=env
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    assert lines, f"node printed no result (rc {proc.returncode}): {proc.stdout[-2000:]} {proc.stderr[-2000:]}"
    out = json.loads(lines[-1])
    assert proc.returncode == 0 and "error" not in out, out.get("error") or proc.stderr[-2000:]
    return out


@pytest.fixture(scope="module")
def node_run(shared_cfg, shared_cell, shared_gw_cfg) -> dict[str, Any]:
    """Every scenario against the module's daemon (worker doubles: one dirty view per cycle)."""
    _, gw = shared_cell
    spy = CommandSpy(shared_cfg)
    try:
        with FakeCell(shared_cfg, dirty_viewpoints={0, 3}):
            wait_until(lambda: gw._values.get(gw._spaces["cell1"].nodeid("Admin/Workers/planner")), 10)
            out = node_plc(shared_gw_cfg.endpoint, ",".join(SCENARIOS), USER, PASSWORD)
        out["commands"] = [json.loads(p).get("cntrl_cmd") for p in spy.payloads]
    finally:
        spy.close()
    return out


def test_node_browses_reads_and_is_refused_as_anonymous(node_run: dict) -> None:
    out = node_run["browse"]
    assert set(out["browse"].values()) == {"Good"}, out["browse"]
    assert out["namespaces"] == {"packml": 2, "cellctl": 3}  # what docs/opcua.md says
    assert out["state"] == 2 and out["unit_mode"] == 1
    assert "BadUserAccessDenied" in out["write_cntrl_cmd"]
    assert "BadUserAccessDenied" in out["call_reset"]
    assert out["state_after"] == 2


def test_node_bad_input_changes_nothing(node_run: dict) -> None:
    out = node_run["bad-input"]
    assert out["cntrl_cmd"] == {k: "BadOutOfRange" for k in ("0", "11", "-1", "2147483647")}
    assert out["cntrl_cmd_double"] == out["cntrl_cmd_string"] == "BadTypeMismatch"
    assert out["change_request_without_command"] == "BadNothingToDo"
    assert "without a command" in out["reject_reason"]
    assert out["start_in_stopped"]["status"] == "BadInvalidState"
    assert "'start' is not allowed in state 'Stopped'" in out["start_in_stopped"]["reason"]
    assert out["state_after"] == 2


@pytest.mark.parametrize("scenario", ["handshake", "methods"])
def test_node_runs_a_cycle(node_run: dict, scenario: str) -> None:
    out = node_run[scenario]
    if scenario == "handshake":
        assert [s["change_request"] for s in out["steps"]] == ["Good", "Good"]
        assert [s["change_request_after"] for s in out["steps"]] == [False, False]
    else:
        assert [(s["status"], s["reason"]) for s in out["steps"]] == [("Good", ""), ("Good", "")]
    seen = out["states_seen"]
    assert seen[0] == (2 if scenario == "handshake" else 17), seen
    assert seen[-1] == 17, seen
    for acting in (15, 3, 6, 16):  # Resetting, Starting, Execute, Completing
        assert acting in seen, seen
    assert out["source_timestamps"] is True
    assert out["processed_after"] == out["processed_before"] + 1
    assert out["defective_after"] == out["defective_before"] + 1
    assert out["last_outcome"] == "completed"


def test_node_sent_exactly_the_accepted_requests(node_run: dict) -> None:
    # bad-input: only the Start call reached the daemon (refused there); then Reset, Start twice
    assert node_run["commands"] == [2, 1, 2, 1, 2]
