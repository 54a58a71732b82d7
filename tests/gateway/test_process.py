"""`cellctl gateway opcua` as its own process; what it and the daemon import."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
import time

from asyncua import Client, ua

import cellctl.gateway.opcua as gateway_pkg
from cellctl.gateway.opcua import CELLCTL_NS
from tests.conftest import free_port


def test_cli_process_serves_and_stops_on_sigterm(cfg, daemon) -> None:
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    sets = [a for ep in cfg.bus.connect for a in ("--set", f'bus.connect=["{ep}"]')]
    proc = subprocess.Popen(
        [sys.executable, "-m", "cellctl", "gateway", "opcua", *sets, "--gw-set", f"endpoint={url}"],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:

        async def read_state() -> int:
            deadline = time.monotonic() + 60
            while True:
                try:
                    async with Client(url, timeout=5) as c:
                        ns = await c.get_namespace_index(CELLCTL_NS)
                        node = c.get_node(ua.NodeId("cell1/Status/StateCurrent", ns))
                        while (v := await node.read_value()) == 0 and time.monotonic() < deadline:
                            await asyncio.sleep(0.1)
                        return v
                except (OSError, asyncio.TimeoutError):
                    assert proc.poll() is None and time.monotonic() < deadline, "the gateway process did not serve"
                    await asyncio.sleep(0.3)

        assert asyncio.run(read_state()) == 2
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=20)
        err = proc.stderr.read() if proc.stderr else ""
    assert rc == 0, err[-2000:]
    assert "OPC UA PackML gateway on" in err


def test_cli_reports_a_bad_gateway_config() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "cellctl", "gateway", "opcua", "--gw-set", "security=[rot13]"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert "security" in out.stderr and "rot13" in out.stderr


def test_exported_members() -> None:
    assert sorted(gateway_pkg.__all__) == sorted(n for n in gateway_pkg.__all__ if hasattr(gateway_pkg, n))
    assert {"OpcuaGateway", "OpcuaConfig", "load_gateway_config", "PACKML_NS"} <= set(gateway_pkg.__all__)


def test_daemon_does_not_import_asyncua_and_the_gateway_is_light() -> None:
    code = (
        "import sys\n"
        "import cellctl.app, cellctl.cli.daemon, cellctl.bus.security\n"
        "from cellctl.cli import build_parser\n"
        "build_parser()\n"
        "print('asyncua' in sys.modules)\n"
        "import cellctl.gateway.opcua.server\n"
        "print(','.join(m for m in ('torch', 'open3d', 'pybullet', 'ompl', 'cv2') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    daemon_has_asyncua, heavy = out.stdout.splitlines()
    assert daemon_has_asyncua == "False"
    assert heavy == "", f"the gateway imported {heavy}"


def test_the_engineers_guide_names_every_node_and_method() -> None:
    import re

    from cellctl.config import project_root
    from cellctl.gateway.opcua import METHODS, VARIABLES

    guide = (project_root() / "docs" / "opcua.md").read_text()
    words = set(re.findall(r"[A-Za-z]+", guide))
    missing = [v.path for v in VARIABLES if not set(v.path.split("/")) <= words]
    missing += [m for m in [*METHODS, "SetUnitMode"] if m not in words]
    assert not missing, f"docs/opcua.md does not name {missing}"
