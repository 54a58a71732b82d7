"""Contract: every command the daemon receives by put gets exactly one Ack on ``cmd/ack``, even in
a burst sent while the machine's CPUs are busy (an outside client once saw 2851 Acks for 3000 puts).

The sender is a plain zenoh process (``burst_sender.py``) that puts with ``CongestionControl.BLOCK``,
as the contract asks of put senders; the daemon's side counts what it received, so a loss is
attributed: never received (the sender's or the router's) or received and not acked (ours).

Where the 149 went: the daemon published Acks with Zenoh's default ``CongestionControl.DROP``; a
client that reads slowly (busy CPU) back-pressures the daemon's transmission queue, and a full
queue drops. ``test_a_slow_consumer_behind_small_buffers_still_gets_every_ack`` makes that
happen on purpose (small socket buffers, one-batch queue, a callback taking 1 ms): with DROP
about half the Acks are lost, with the BLOCK publisher none.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from cellctl.app import build_cell

HERE = Path(__file__).parent

BUSY = "import time\nend = time.monotonic() + 120\nwhile time.monotonic() < end: pass\n"

TIGHT_DAEMON = {
    "transport": {
        "link": {
            "tx": {
                "queue": {"size": {"data": 1}, "congestion_control": {"drop": {"wait_before_drop": 1}}},
                "batch_size": 2048,
            },
            "tcp": {"so_sndbuf": 4096},
        }
    }
}
"""Zenoh tuning that makes back-pressure reach the daemon's transmission queue within a few Acks."""


@pytest.fixture
def cell(cfg):
    c = build_cell(cfg, identification=(None, None))
    yield c
    c.close()


@pytest.fixture
def tight_cell(cfg, tmp_path: Path):
    path = tmp_path / "tight.json5"
    path.write_text(json.dumps(TIGHT_DAEMON))
    cfg.bus.zenoh_config = path
    c = build_cell(cfg, identification=(None, None))
    yield c
    c.close()


def _burst(cfg, cell, n: int, monkeypatch, *, busy: bool, ack_delay_s: float = 0.0, client: dict | None = None):
    """Send ``n`` hostile puts (a 50 ms pause every 200); return the sender's report and what the daemon received."""
    sup = cell.supervisor
    received = Counter[str]()
    real = sup.apply_command

    def counting(payload: bytes):
        received["all"] += 1
        return real(payload)

    monkeypatch.setattr(sup, "apply_command", counting)
    load = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(os.cpu_count() or 2)] if busy else []
    args = [cfg.bus.listen[0], cfg.cell_id, str(n), "200", "0.05", "block", str(ack_delay_s), json.dumps(client or {})]
    try:
        out = subprocess.run(
            [sys.executable, str(HERE / "burst_sender.py"), *args], capture_output=True, text=True, timeout=180
        )
    finally:
        for p in load:
            p.kill()
            p.wait()
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout), received["all"]


def _assert_every_put_acked(report: dict, received: int, n: int, cell) -> None:
    ids = Counter(report["ids"])
    assert received == n, f"the daemon received {received} of {n} puts"
    assert report["acks"] == n, f"{report['acks']} Acks for {n} puts ({received} received)"
    assert set(ids) == {f"b-{i}" for i in range(n)}  # every Ack names its request, despite wrong type/v
    assert max(ids.values()) == 1
    assert cell.supervisor.state == "Stopped"  # all of them refused


def test_a_burst_of_hostile_puts_under_cpu_load_gets_every_ack(cfg, cell, monkeypatch) -> None:
    report, received = _burst(cfg, cell, 600, monkeypatch, busy=True)
    _assert_every_put_acked(report, received, 600, cell)


def test_a_slow_consumer_behind_small_buffers_still_gets_every_ack(cfg, tight_cell, monkeypatch) -> None:
    report, received = _burst(
        cfg, tight_cell, 1000, monkeypatch, busy=False, ack_delay_s=0.001, client={"transport/link/tcp/so_rcvbuf": 4096}
    )
    _assert_every_put_acked(report, received, 1000, tight_cell)


@pytest.mark.slow
def test_three_thousand_hostile_puts_under_cpu_load_get_every_ack(cfg, cell, monkeypatch) -> None:
    report, received = _burst(cfg, cell, 3000, monkeypatch, busy=True)
    _assert_every_put_acked(report, received, 3000, cell)
