"""`cellctl cmd` and `cellctl status` speak the PLC contract through the one client, `PlcClient` (issue 33 item 5)."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

from cellctl.bus.plc_client import PlcClient
from cellctl.cli import main
from cellctl.config import CellConfig
from tests.conftest import cfg_overrides
from tests.fakes.workers import FakeCell, fake_identify


def test_cmd_sends_through_the_plc_client_by_query_and_by_put_and_status_prints_the_status(
    cfg: CellConfig, tmp_path: Path, port: int, capsys, monkeypatch
) -> None:
    from cellctl.app import build_cell
    from cellctl.geometry.catalog import load_catalog

    sent: list[tuple[str, bool]] = []
    real_send = PlcClient.send

    def spy(self: PlcClient, cmd, timeout: float = 10.0, *, put: bool = False):
        sent.append((cmd.request_id, put))
        return real_send(self, cmd, timeout, put=put)

    monkeypatch.setattr(PlcClient, "send", spy)
    sets = [a for ov in cfg_overrides(tmp_path, port) for a in ("--set", ov)]
    cell = build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    try:
        time.sleep(0.2)
        with FakeCell(cfg):
            assert main(["cmd", "reset", "--wait", "Idle", "--timeout", "10", *sets]) == 0
            ack_line, reached = capsys.readouterr().out.strip().splitlines()
            ack = json.loads(ack_line)
            assert ack["accepted"] is True and json.loads(reached) == {"reached": "Idle"}
            # the client's request ids: cli-<boot token>-<n>, echoed in the Ack
            assert re.fullmatch(r"cli-[0-9a-f]{6}-1", ack["request_id"]) and sent == [(ack["request_id"], False)]
            assert main(["cmd", "--unit-mode", "maintenance", "--put", "--user", "t:qa", *sets]) == 0
            ack = json.loads(capsys.readouterr().out)
            assert ack["accepted"] is True and ack["request_id"].startswith("cli-") and sent[-1][1] is True
            assert main(["status", *sets]) == 0
            status = json.loads(capsys.readouterr().out)
            assert status["state"] == "Idle" and status["unit_mode"] == "maintenance"
    finally:
        cell.close()
