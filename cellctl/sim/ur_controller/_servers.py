"""The emulator's sockets: RTDE (30004), script (30003 and 30002), dashboard (29999), control.

Each accepted connection gets a thread that reads it; the 500 Hz loop sends the RTDE data
packages. Ports are those ur-rtde hard-codes (it takes a host, not ports, for RTDE and the script
interface), so two emulators on one machine need two loopback addresses (127.0.0.x).
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from cellctl.errors import ConfigError
from cellctl.sim.ur_controller import _protocol as p
from cellctl.sim.ur_controller._controller import RobotMode, SafetyMode, UrController

__all__ = ["Ports", "UrControllerServers"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


_ZERO: dict[str, object] = {
    "BOOL": False,
    "UINT8": 0,
    "UINT32": 0,
    "UINT64": 0,
    "INT32": 0,
    "DOUBLE": 0.0,
    "VECTOR3D": [0.0] * 3,
    "VECTOR6D": [0.0] * 6,
    "VECTOR6INT32": [0] * 6,
    "VECTOR6UINT32": [0] * 6,
}


@dataclass(frozen=True)
class Ports:
    rtde: int = 30004
    script: int = 30003
    primary: int = 30002
    dashboard: int = 29999
    control: int = 30099
    """The emulator's own fault-injection socket (not a UR port; one text command a line)."""


@dataclass
class _RtdeConn:
    sock: socket.socket
    send_lock: threading.Lock = field(default_factory=threading.Lock)
    out_names: list[str] = field(default_factory=list)
    out_types: list[str] = field(default_factory=list)
    out_struct: struct.Struct | None = None
    out_id: int = 0
    divisor: int = 1
    inputs: dict[int, tuple[list[str], struct.Struct]] = field(default_factory=dict)
    next_out_id: int = 1
    next_in_id: int = 1
    """Output and input recipes are numbered separately (ur-rtde's recipe ids count inputs only)."""
    started: bool = False
    closed: bool = False

    def send(self, data: bytes) -> None:
        with self.send_lock:
            self.sock.sendall(data)


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("peer closed")
        buf += chunk
    return buf


class UrControllerServers:
    """Listen on ``host`` and serve ``ctl`` until :meth:`close`.

    Raises:
        ConfigError: ``host`` is not a loopback address, or a port is taken.
    """

    RATE_HZ = 500.0

    def __init__(self, ctl: UrController, host: str = "127.0.0.1", ports: Ports | None = None) -> None:
        try:
            if not ipaddress.ip_address(host).is_loopback:
                raise ValueError
        except ValueError:
            raise ConfigError(f"ur-controller host is {host!r}; expected a loopback address (127.0.0.0/8)") from None
        self.ctl = ctl
        self.host = host
        self.ports = ports or Ports()
        self._closed = threading.Event()
        self._conns: list[_RtdeConn] = []
        self._socks: set[socket.socket] = set()
        self._lk = threading.Lock()
        self._claimed: dict[str, _RtdeConn] = {}
        self.refuse_until = 0.0
        self.frozen_until = 0.0
        self.inputs_in_use: set[str] = set()
        """Input names the controller reports IN_USE (as when a fieldbus adapter holds them)."""
        self.packages_sent = 0
        self._listeners: list[socket.socket] = []
        handlers: list[tuple[int, Callable[[socket.socket], None]]] = [
            (self.ports.rtde, self._serve_rtde),
            (self.ports.script, self._serve_script),
            (self.ports.primary, self._serve_script),
            (self.ports.dashboard, self._serve_dashboard),
            (self.ports.control, self._serve_control),
        ]
        try:
            for port, fn in handlers:
                ls = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                ls.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                ls.bind((host, port))
                ls.listen(8)
                self._listeners.append(ls)
                threading.Thread(target=self._accept, args=(ls, fn), name=f"ur-accept-{port}", daemon=True).start()
        except OSError as err:
            self.close()
            raise ConfigError(f"ur-controller cannot listen on {host}:{port}: {err}") from err
        threading.Thread(target=self._loop, name="ur-controller-500hz", daemon=True).start()

    # --- plumbing ---------------------------------------------------------------------------

    def _accept(self, ls: socket.socket, fn: Callable[[socket.socket], None]) -> None:
        while not self._closed.is_set():
            try:
                s, _ = ls.accept()
            except OSError:
                return
            control = fn == self._serve_control  # the emulator's own port: never dropped (it injects the drop)
            if not control and time.monotonic() < self.refuse_until:
                s.close()
                continue
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if not control:
                with self._lk:
                    self._socks.add(s)
            threading.Thread(target=self._run, args=(fn, s), daemon=True).start()

    def _run(self, fn: Callable[[socket.socket], None], s: socket.socket) -> None:
        try:
            fn(s)
        except (OSError, ConnectionError, UnicodeDecodeError, struct.error, ValueError) as err:
            log.info("connection ended: %r", err)
        finally:
            with self._lk:
                self._socks.discard(s)
                for c in [c for c in self._conns if c.sock is s]:
                    c.closed = True
                    self._conns.remove(c)
                    for n in [n for n, o in self._claimed.items() if o is c]:
                        del self._claimed[n]
            try:
                s.close()
            except OSError:
                pass

    def drop_connections(self, refuse_s: float = 0.0) -> None:
        """Close every client connection (and refuse new ones for ``refuse_s``)."""
        self.refuse_until = time.monotonic() + refuse_s
        with self._lk:
            socks = list(self._socks)
        for s in socks:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def freeze(self, seconds: float) -> None:
        """Stall the controller: no motion, no data packages, for ``seconds``."""
        self.frozen_until = time.monotonic() + seconds

    def close(self) -> None:
        self._closed.set()
        for ls in self._listeners:
            try:
                ls.close()
            except OSError:
                pass
        self.drop_connections()

    # --- the 500 Hz loop --------------------------------------------------------------------

    def _loop(self) -> None:
        period = 1.0 / self.RATE_HZ
        last = time.monotonic()
        nxt = last + period
        n = 0
        while not self._closed.is_set():
            delay = nxt - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            now = time.monotonic()
            nxt = max(nxt + period, now)  # late: do not catch up with a burst
            if now < self.frozen_until:
                last = now  # a stalled controller's time does not advance its motion
                continue
            self.ctl.tick(min(now - last, 0.1))
            last = now
            n += 1
            with self._lk:
                conns = [c for c in self._conns if c.started and c.out_struct is not None and n % c.divisor == 0]
            if not conns:
                continue
            try:
                self._send_data(conns)
            except Exception:  # a bug in one package must not stop the controller's clock
                log.exception("ur-controller: building a data package failed")

    def _value(self, snap: dict[str, object], name: str, kind: str) -> object:
        if name in snap:
            return snap[name]
        if "_register_" in name:
            return self.ctl.register(name)
        return _ZERO[kind]

    def _send_data(self, conns: list[_RtdeConn]) -> None:
        with self.ctl.lock:
            snap = self.ctl.snapshot()
            rows = [
                (c, [self._value(snap, k, t) for k, t in zip(c.out_names, c.out_types, strict=True)]) for c in conns
            ]
        for c, vals in rows:
            flat: list[object] = []
            for v in vals:
                flat.extend(v) if isinstance(v, list) else flat.append(v)  # type: ignore[func-returns-value]
            try:
                assert c.out_struct is not None
                c.send(p.package(p.RTDE_DATA_PACKAGE, bytes([c.out_id]) + c.out_struct.pack(*flat)))
                self.packages_sent += 1
            except OSError:
                c.closed = True

    # --- RTDE -------------------------------------------------------------------------------

    def _serve_rtde(self, s: socket.socket) -> None:
        c = _RtdeConn(s)
        with self._lk:
            self._conns.append(c)
        proto = 1
        while True:
            size, kind = p.HEADER.unpack(_recv_exact(s, p.HEADER.size))
            body = _recv_exact(s, size - p.HEADER.size)
            if kind == p.RTDE_REQUEST_PROTOCOL_VERSION:
                (ver,) = struct.unpack(">H", body[:2])
                ok = ver in (1, 2)
                proto = ver if ok else proto
                c.send(p.package(kind, bytes([1 if ok else 0])))
            elif kind == p.RTDE_GET_URCONTROL_VERSION:
                c.send(p.package(kind, struct.pack(">IIII", *self.ctl.identity.version)))
            elif kind == p.RTDE_CONTROL_PACKAGE_SETUP_OUTPUTS:
                freq = struct.unpack(">d", body[:8])[0] if proto >= 2 else self.RATE_HZ
                names = [n for n in body[8 if proto >= 2 else 0 :].decode().split(",") if n]
                types = [p.output_type(n) or "NOT_FOUND" for n in names]
                if "NOT_FOUND" in types or not (0 < freq <= self.RATE_HZ):
                    c.send(p.package(kind, bytes([0]) + ",".join(types).encode()))
                    continue
                c.out_names, c.out_types = names, types
                c.out_struct = struct.Struct(">" + "".join(p.FORMATS[t] for t in types))
                c.divisor = max(1, round(self.RATE_HZ / freq))
                c.out_id = c.next_out_id
                c.next_out_id += 1
                c.send(p.package(kind, bytes([c.out_id]) + ",".join(types).encode()))
            elif kind == p.RTDE_CONTROL_PACKAGE_SETUP_INPUTS:
                names = [n for n in body.decode().split(",") if n]
                with self._lk:
                    types = []
                    for n in names:
                        t = p.input_type(n)
                        owner = self._claimed.get(n)
                        if t is None:
                            types.append("NOT_FOUND")
                        elif n in self.inputs_in_use or (owner is not None and owner is not c):
                            types.append("IN_USE")
                        else:
                            types.append(t)
                    ok = all(t not in ("NOT_FOUND", "IN_USE") for t in types)
                    if ok:
                        for n in names:
                            self._claimed[n] = c
                rid = c.next_in_id if ok else 0
                if ok:
                    c.inputs[rid] = (names, struct.Struct(">" + "".join(p.FORMATS[t] for t in types)))
                    c.next_in_id += 1
                c.send(p.package(kind, bytes([rid]) + ",".join(types).encode()))
            elif kind == p.RTDE_CONTROL_PACKAGE_START:
                c.started = c.out_struct is not None or bool(c.inputs)
                c.send(p.package(kind, bytes([1 if c.started else 0])))
            elif kind == p.RTDE_CONTROL_PACKAGE_PAUSE:
                c.started = False
                c.send(p.package(kind, bytes([1])))
            elif kind == p.RTDE_DATA_PACKAGE:
                rec = c.inputs.get(body[0])
                if rec is None:
                    continue  # an unknown recipe id: the controller drops the package
                names, st = rec
                if len(body) - 1 < st.size:
                    log.info("recipe %d: %d bytes for %d (%s)", body[0], len(body) - 1, st.size, names)
                    continue
                vals = st.unpack(body[1 : 1 + st.size])
                with self.ctl.lock:
                    for n, v in zip(names, vals, strict=True):
                        self.ctl.set_input(n, v)

    # --- script interface -------------------------------------------------------------------

    def _serve_script(self, s: socket.socket) -> None:
        buf = ""
        script: list[str] | None = None
        while True:
            data = s.recv(65536)
            if not data:
                return
            buf += data.decode("utf-8", errors="replace")
            *lines, buf = buf.split("\n")
            for line in lines:
                if script is None:
                    if line.startswith("def "):
                        script = [line]
                    continue  # a one-line statement outside a program: not emulated
                script.append(line)
                if line.rstrip() == "end":  # the program's own end is the only one at column 0
                    self.ctl.upload_script("\n".join(script) + "\n")
                    script = None

    # --- dashboard --------------------------------------------------------------------------

    def _serve_dashboard(self, s: socket.socket) -> None:
        f = s.makefile("rwb", buffering=0)
        f.write(b"Connected: Universal Robots Dashboard Server\n")
        for raw in f:
            cmd = raw.decode().strip()
            reply = self._dashboard(cmd)
            f.write((reply + "\n").encode())
            if cmd == "quit":
                return

    def _dashboard(self, cmd: str) -> str:
        ctl = self.ctl
        low = cmd.lower()
        with ctl.lock:
            if low == "robotmode":
                return f"Robotmode: {ctl.robot_mode.name}"
            if low == "safetymode":
                return f"Safetymode: {ctl.safety_mode.name}"
            if low == "safetystatus":
                return f"Safetystatus: {ctl.safety_mode.name}"
            if low == "polyscopeversion":
                return f"URSoftware {ctl.identity.polyscope} (emulated)"
            if low == "get serial number":
                return ctl.identity.serial
            if low == "get robot model":
                return ctl.identity.model
            if low == "is in remote control":
                return "true" if ctl.remote_control else "false"
            if low == "running":
                return f"Program running: {'true' if ctl.runtime_state == 2 else 'false'}"
            if low == "programstate":
                return "PLAYING rtde_control" if ctl.runtime_state == 2 else "STOPPED <unnamed>"
            if low == "get loaded program":
                return "No program loaded"
            if low == "quit":
                return "Disconnected"
            if low == "close popup":
                return "closing popup"
            if low.startswith("popup "):
                return "showing popup"
            if low.startswith("addtolog "):
                return "Added log message"
            if low == "close safety popup":
                return "closing safety popup"
            control = {
                "power on": lambda: ctl.power(True),
                "power off": lambda: ctl.power(False),
                "brake release": ctl.brake_release,
                "unlock protective stop": ctl.unlock_protective_stop,
                "stop": ctl.stop_program,
                "play": lambda: "Failed to execute: play",
                "restart safety": self._restart_safety,
            }
            fn = control.get(low)
            if fn is None:
                if low.startswith("load "):
                    return f"File not found: {cmd[5:]}"
                return f"could not understand: '{cmd}'"
            if not ctl.remote_control:
                return "Command is not allowed due to safety reasons (the robot is in local control)"
            return fn()

    def _restart_safety(self) -> str:
        ctl = self.ctl
        if ctl.safety_mode in (SafetyMode.VIOLATION, SafetyMode.FAULT, SafetyMode.PROTECTIVE_STOP):
            ctl.safety_mode = SafetyMode.NORMAL
            ctl.robot_mode = RobotMode.POWER_OFF
        return "Restarting safety"

    # --- fault injection --------------------------------------------------------------------

    def _serve_control(self, s: socket.socket) -> None:
        f = s.makefile("rwb", buffering=0)
        for raw in f:
            try:
                reply = self.inject(raw.decode().strip())
            except ValueError as err:
                reply = f"error: {err}"
            f.write((reply + "\n").encode())

    def inject(self, command: str) -> str:
        """Apply one fault-injection command; returns ``ok …``.

        Commands: ``protective_stop``, ``estop``, ``estop_release``, ``safeguard``,
        ``safeguard_reset``, ``reduced``, ``reduced_off``, ``drop [refuse_s]``, ``stall <s>``,
        ``power_off``, ``mode <RUNNING|IDLE|POWER_OFF>``, ``local``, ``remote``,
        ``inputs_in_use <name,…>``, ``slider <0..1>``, ``reset`` (healthy, RUNNING), ``state``.

        Raises:
            ValueError: an unknown command or a bad argument (named).
        """
        word, _, arg = command.partition(" ")
        ctl = self.ctl
        if word == "protective_stop":
            ctl.protective_stop(arg or "injected")
        elif word == "estop":
            ctl.emergency_stop(True)
        elif word == "estop_release":
            ctl.emergency_stop(False)
        elif word == "safeguard":
            ctl.safeguard_stop(True)
        elif word == "safeguard_reset":
            ctl.safeguard_stop(False)
        elif word == "reduced":
            ctl.reduced_mode(True)
        elif word == "reduced_off":
            ctl.reduced_mode(False)
        elif word in ("drop", "stall"):
            try:
                secs = float(arg or 0.0)
            except ValueError:
                raise ValueError(f"{word} takes seconds; got {arg!r}") from None
            if word == "drop":
                self.drop_connections(secs)
            else:
                self.freeze(secs)
        elif word == "power_off":
            ctl.power(False)
        elif word == "mode":
            try:
                mode = RobotMode[arg.strip().upper()]
            except KeyError:
                raise ValueError(f"mode takes a robot mode name (RUNNING, IDLE, POWER_OFF); got {arg!r}") from None
            with ctl.lock:
                if mode != RobotMode.RUNNING:
                    ctl.power(False)
                ctl.robot_mode = mode
        elif word == "reset":
            with ctl.lock:
                ctl.emergency_stop(False)
                ctl.power(False)
                ctl.safety_mode = SafetyMode.NORMAL
                ctl.robot_mode = RobotMode.RUNNING
                ctl.remote_control = True
                ctl.speed_slider = 1.0
            self.inputs_in_use = set()
            self.refuse_until = self.frozen_until = 0.0
        elif word == "slider":
            try:
                f = float(arg)
            except ValueError:
                raise ValueError(f"slider takes a fraction in [0, 1]; got {arg!r}") from None
            if not 0.0 <= f <= 1.0:
                raise ValueError(f"slider takes a fraction in [0, 1]; got {f}")
            ctl.speed_slider = f
        elif word in ("local", "remote"):
            ctl.remote_control = word == "remote"
        elif word == "inputs_in_use":
            self.inputs_in_use = {n for n in arg.split(",") if n}
        elif word == "state":
            with ctl.lock:
                return (
                    f"ok {ctl.robot_mode.name} {ctl.safety_mode.name} runtime={ctl.runtime_state.name} "
                    f"q={ctl.q.tolist()} moving={ctl.moving}"
                )
        else:
            raise ValueError(
                f"unknown fault command {word!r}; expected one of protective_stop, estop, estop_release, safeguard, "
                "safeguard_reset, reduced, reduced_off, drop, stall, power_off, mode, local, remote, inputs_in_use, "
                "slider, reset, state"
            )
        return f"ok {word}"
