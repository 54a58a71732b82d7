"""The emulator as a child process (ur-rtde's calls hold the GIL while they wait on sockets, so
an emulator inside the same Python process as ur-rtde would deadlock it)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from cellctl.errors import ConfigError

__all__ = ["EmulatorProcess", "free_loopback_host"]


def free_loopback_host(start: int | None = None) -> str:
    """A 127.x.y.z address whose UR ports (30004, 30003, 30002, 29999) are free.

    ur-rtde fixes the ports, so concurrent emulators (parallel test runs) differ by address;
    the first candidate derives from the process id (deterministic per process).
    """
    n = os.getpid() if start is None else start
    for k in range(200):
        v = (n + k * 7919) % (250 * 250)
        host = f"127.77.{v // 250 + 1}.{v % 250 + 2}"
        ok = True
        for port in (30004, 30003, 30002, 29999, 30099):
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
                try:
                    s.bind((host, port))
                except OSError:
                    ok = False
                    break
        if ok:
            return host
    raise ConfigError("no free loopback address for a UR controller emulator")


class EmulatorProcess:
    """``cellctl sim ur-controller`` in a child process; :meth:`inject` sends fault commands.

    Args:
        host: loopback address to listen on.
        overrides: ``--set`` config overrides for the child (``sim.ur_controller.*``).
        config: config file for the child.
        log_path: where the child's stderr goes (default: discarded).
        verbose: the child's log level: 0 warnings, 1 info (programs started), 2 debug (every command).

    Raises:
        ConfigError: the child did not report ready within ``timeout_s``.
    """

    def __init__(
        self,
        host: str,
        overrides: list[str] | None = None,
        config: Path | str | None = None,
        log_path: Path | None = None,
        timeout_s: float = 60.0,
        verbose: int = 0,
    ) -> None:
        self.host = host
        self.overrides = list(overrides or [])
        cmd = [sys.executable, "-m", "cellctl", *(["-" + "v" * verbose] if verbose else []), "sim", "ur-controller"]
        cmd += ["--host", host]
        if config is not None:
            cmd += ["--config", str(config)]
        for o in self.overrides:
            cmd += ["--set", o]
        self._log = open(log_path, "wb") if log_path is not None else subprocess.DEVNULL
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self.control_port = 30099
        for o in self.overrides:
            if o.startswith("sim.ur_controller.control_port="):
                self.control_port = int(o.split("=", 1)[1])
        deadline = time.monotonic() + timeout_s
        assert self.proc.stderr is not None
        while True:
            line = self.proc.stderr.readline().decode(errors="replace")
            if "ur-controller ready" in line:
                break
            if not line and self.proc.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise ConfigError(f"the UR controller emulator did not start on {host}: {line.strip()}")
        # keep draining stderr so the child never blocks on a full pipe
        import threading

        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            if self._log is not subprocess.DEVNULL:
                self._log.write(line)  # type: ignore[union-attr]
                self._log.flush()  # type: ignore[union-attr]

    def inject(self, command: str, timeout_s: float = 5.0) -> str:
        """Send one fault-injection line (see :meth:`UrControllerServers.inject`); returns the reply."""
        with socket.create_connection((self.host, self.control_port), timeout=timeout_s) as s:
            s.sendall((command + "\n").encode())
            buf = b""
            while not buf.endswith(b"\n"):
                chunk = s.recv(4096)
                if not chunk:
                    break
                buf += chunk
        return buf.decode().strip()

    def state(self) -> dict[str, object]:
        """The controller's own view: modes, runtime state, joints, moving."""
        reply = self.inject("state")
        _, robot, safety, runtime, rest = reply.split(" ", 4)
        q_txt, moving = rest.rsplit(" moving=", 1)
        q = [float(x) for x in q_txt.split("=", 1)[1].strip("[]").split(",")]
        return {"robot_mode": robot, "safety_mode": safety, "runtime": runtime.split("=")[1], "q": q,
                "moving": moving == "True"}  # fmt: skip

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._log is not subprocess.DEVNULL:
            self._log.close()  # type: ignore[union-attr]

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
