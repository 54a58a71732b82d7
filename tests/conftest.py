"""Shared fixtures: unique loopback ports, a config whose outputs go to a temp dir."""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import pytest

from cellctl.config import CellConfig, load_config

_ports = itertools.count(20000 + (os.getpid() % 200) * 50)


def free_port() -> int:
    """A loopback port unique within this test session (Zenoh binds it for real)."""
    import socket

    while True:
        port = next(_ports)
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
                return port
            except OSError:
                continue


@pytest.fixture
def port() -> int:
    return free_port()


def cfg_overrides(tmp_path: Path, port: int) -> list[str]:
    """The ``--set`` overrides of the ``cfg`` fixture (for tests that start ``cellctl`` processes)."""
    ep = f'["tcp/127.0.0.1:{port}"]'
    return [
        f"bus.listen={ep}",
        f"bus.connect={ep}",
        f"recording.dir={tmp_path / 'logs'}",
        f"recording.index={tmp_path / 'logs' / 'cells.db'}",
        f"planner.plans_dir={tmp_path / 'plans'}",
        "supervisor.status_period_s=0.2",
        "robot.settle_s=0",
        # the worker doubles (tests/fakes) answer one station's plan and see a few faces: single-station
        # cycles with no coverage minimum; the whole-bin default and the gate have their own tests
        # (tests/supervisor/test_whole_default.py)
        "planner.whole.enabled=false",
        "classifier.verdict.min_seen_fraction={}",
        # ...and their views carry labels, not the heat maps and faces the default faces rule fuses:
        # the any-view rule decides their bins (the faces rule has its own tests, tests/classify)
        "classifier.verdict.rule=views",
    ]


@pytest.fixture
def cfg(tmp_path: Path, port: int) -> CellConfig:
    """The default cell config on a private port, logging under tmp_path, fast timeouts, single-station."""
    return load_config(None, cfg_overrides(tmp_path, port))
