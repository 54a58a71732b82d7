"""A TCP relay that adds latency and loss to a link between two hosts (namespaces).

The machines this runs on have no ``netem`` qdisc and no iptables/nft, so a link's delay and
loss come from this relay: a router connects to the relay's listen address instead of its
peer's, and the relay forwards each chunk after ``delay_ms`` (± ``jitter_ms``). Zenoh runs over
TCP here, and TCP never loses bytes: a lost segment costs its retransmission. So ``loss`` is
the probability that a chunk is held back one retransmission timeout (``rto_ms``, 200 ms as
Linux's minimum RTO) before it goes; order is kept, as TCP keeps it.

The settings are re-read from ``control`` (a JSON file) every 100 ms, so a test changes them
mid-run by rewriting the file. Random draws use ``seed``. Run in the host that owns the
listen address::

    python -c "import sys; from cellctl.bench.reliability.relay import main; main(sys.argv[1])" SPEC.json

``SPEC`` names ``listen`` (host, port), ``target`` (host, port) and ``control`` (path).
"""

from __future__ import annotations

import json
import random
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from cellctl.errors import ConfigError

__all__ = ["LinkShape", "Relay", "main"]


@dataclass(frozen=True)
class LinkShape:
    """What the relay does to each chunk."""

    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    loss: float = 0.0
    rto_ms: float = 200.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss <= 1.0:
            raise ConfigError(f"relay loss {self.loss!r} must be a probability in [0, 1]")
        for name in ("delay_ms", "jitter_ms", "rto_ms"):
            if getattr(self, name) < 0:
                raise ConfigError(f"relay {name} {getattr(self, name)!r} must be >= 0")

    @classmethod
    def from_file(cls, path: Path) -> LinkShape:
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as err:
            raise ConfigError(f"relay control {str(path)!r} unreadable: {err}") from err
        allowed = set(cls.__dataclass_fields__)
        extra = set(data) - allowed
        if extra:
            raise ConfigError(f"relay control keys {sorted(extra)} unknown; allowed: {sorted(allowed)}")
        return cls(**data)


class Relay:
    """Forward TCP connections from ``listen`` to ``target`` through a shaped delay line."""

    def __init__(self, listen: tuple[str, int], target: tuple[str, int], control: Path) -> None:
        self.listen, self.target, self.control = listen, target, Path(control)
        self.shape = LinkShape.from_file(self.control) if self.control.exists() else LinkShape()
        self._rng = random.Random(self.shape.seed)
        self._rng_lock = threading.Lock()
        self._stop = threading.Event()
        self.chunks = 0
        self.held = 0

    def _release_time(self, last: float) -> float:
        s = self.shape
        with self._rng_lock:
            extra = s.delay_ms + (self._rng.uniform(-s.jitter_ms, s.jitter_ms) if s.jitter_ms else 0.0)
            lost = s.loss > 0 and self._rng.random() < s.loss
        if lost:
            extra += s.rto_ms
            self.held += 1
        self.chunks += 1
        return max(last, time.monotonic() + max(extra, 0.0) / 1000.0)  # TCP keeps order

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        line: deque[tuple[float, bytes]] = deque()
        cond = threading.Condition()
        done = threading.Event()

        def sender() -> None:
            while True:
                with cond:
                    while not line and not done.is_set():
                        cond.wait(0.1)
                    if not line and done.is_set():
                        break
                    due, data = line[0]
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(min(wait, 0.05))
                    continue
                with cond:
                    line.popleft()
                try:
                    dst.sendall(data)
                except OSError:
                    break
            _close(dst)

        t = threading.Thread(target=sender, daemon=True)
        t.start()
        last = 0.0
        try:
            while not self._stop.is_set():
                data = src.recv(65536)
                if not data:
                    break
                last = self._release_time(last)
                with cond:
                    line.append((last, data))
                    cond.notify()
        except OSError:
            pass
        done.set()
        t.join(timeout=5)
        _close(src)

    def _watch_control(self) -> None:
        mtime = None
        while not self._stop.wait(0.1):
            try:
                m = self.control.stat().st_mtime_ns
            except OSError:
                continue
            if m != mtime:
                mtime = m
                try:
                    self.shape = LinkShape.from_file(self.control)
                    with self._rng_lock:
                        self._rng = random.Random(self.shape.seed)
                except ConfigError:
                    pass  # a half-written file; the next poll reads it whole

    def serve(self) -> None:
        threading.Thread(target=self._watch_control, daemon=True).start()
        srv = socket.create_server(self.listen, reuse_port=False)
        print(f"relay {self.listen} -> {self.target} listening", flush=True)
        while not self._stop.is_set():
            client, _ = srv.accept()
            try:
                upstream = socket.create_connection(self.target, timeout=5)
            except OSError:
                _close(client)
                continue
            upstream.settimeout(None)
            for s in (client, upstream):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=self._pump, args=(client, upstream), daemon=True).start()
            threading.Thread(target=self._pump, args=(upstream, client), daemon=True).start()


def _close(s: socket.socket) -> None:
    try:
        s.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    s.close()


def main(spec_path: str) -> None:
    """Run a relay from a JSON spec file (see the module docstring); blocks until killed."""
    spec = json.loads(Path(spec_path).read_text())
    Relay(tuple(spec["listen"]), tuple(spec["target"]), Path(spec["control"])).serve()  # type: ignore[arg-type]
