"""``cellctl`` with the bin-identification double, as a process tests can SIGKILL (tests only).

``python -m tests.fakes.daemon run --set ...`` is ``cellctl run`` except that the identify
step uses :func:`tests.fakes.workers.fake_identify`: the worker doubles send flat grey
images, in which the real ChArUco identification would (rightly) find no bin.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from cellctl import app
from cellctl.cli import main
from cellctl.config import CellConfig
from tests.fakes.workers import FakeCell, fake_identify


def fake_identification(cfg: CellConfig) -> tuple[Any, Any]:
    from cellctl.geometry.catalog import load_catalog

    return fake_identify, load_catalog(cfg.path(cfg.catalog))


def live_daemon(cfg: CellConfig) -> app.Cell:
    """The daemon in this process (router, supervisor) with the identification double; close it."""
    return app.build_cell(cfg, identification=fake_identification(cfg))


def record_a_cycle(cfg: CellConfig) -> Path:
    """Run one real cycle (Reset, Start → Complete) on a daemon of its own, with worker doubles; its MCAP."""
    from cellctl.bus.plc_client import PlcClient

    cell = live_daemon(cfg)
    plc = PlcClient(cfg, "rec")
    try:
        time.sleep(0.2)
        with FakeCell(cfg):
            assert plc.command("reset", timeout=5).accepted
            assert plc.wait_for(lambda s: s.state == "Idle", 10) is not None
            assert plc.command("start", timeout=5).accepted
            assert plc.wait_for(lambda s: s.state == "Complete", 30) is not None
            res = plc.results.get(timeout=5)
    finally:
        plc.close()
        cell.close()
    return cfg.path(res.log)


if __name__ == "__main__":
    app.load_identification = fake_identification  # the composition root's one seam for identification
    sys.exit(main(sys.argv[1:]))
