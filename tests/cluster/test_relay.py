"""The latency/loss relay on loopback: bytes intact and in order, delay added both ways, settings live."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import pytest

from cellctl.bench.reliability.relay import LinkShape, Relay
from cellctl.errors import ConfigError
from tests.conftest import free_port


def _echo_server(port: int) -> None:
    srv = socket.create_server(("127.0.0.1", port))

    def serve() -> None:
        while True:
            c, _ = srv.accept()
            threading.Thread(
                target=lambda c=c: [c.sendall(d) for d in iter(lambda: c.recv(65536), b"")], daemon=True
            ).start()

    threading.Thread(target=serve, daemon=True).start()


def _relay(tmp: Path, shape: dict) -> tuple[int, Path]:
    echo, port = free_port(), free_port()
    _echo_server(echo)
    ctl = tmp / "ctl.json"
    ctl.write_text(json.dumps(shape))
    relay = Relay(("127.0.0.1", port), ("127.0.0.1", echo), ctl)
    threading.Thread(target=relay.serve, daemon=True).start()
    deadline = time.monotonic() + 5
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return port, ctl
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def _rtt(sock: socket.socket, payload: bytes) -> tuple[float, bytes]:
    t = time.monotonic()
    sock.sendall(payload)
    got = b""
    while len(got) < len(payload):
        got += sock.recv(65536)
    return time.monotonic() - t, got


def test_bytes_arrive_intact_and_in_order_with_delay_and_loss(tmp_path: Path) -> None:
    port, _ = _relay(tmp_path, {"delay_ms": 5.0, "jitter_ms": 4.0, "loss": 0.3, "rto_ms": 20.0, "seed": 1})
    data = bytes(range(256)) * 4096  # 1 MiB
    with socket.create_connection(("127.0.0.1", port)) as s:
        _, got = _rtt(s, data)
    assert got == data


def test_delay_is_added_in_both_directions_and_changes_live(tmp_path: Path) -> None:
    port, ctl = _relay(tmp_path, {"delay_ms": 100.0})
    with socket.create_connection(("127.0.0.1", port)) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        slow, _ = _rtt(s, b"ping")
        assert slow >= 0.2  # 100 ms out, 100 ms back: a lower bound, whatever the load
        ctl.write_text(json.dumps({"delay_ms": 0.0, "loss": 1.0, "rto_ms": 150.0}))
        time.sleep(0.4)  # the relay re-reads its control file every 100 ms
        lossy, _ = _rtt(s, b"ping")
        assert lossy >= 0.3  # every chunk held one RTO each way


def test_bad_settings_are_refused_by_name(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="relay loss 1.5 must be a probability"):
        LinkShape(loss=1.5)
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"delay": 3}))
    with pytest.raises(ConfigError, match=r"relay control keys \['delay'\] unknown"):
        LinkShape.from_file(p)
