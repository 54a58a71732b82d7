"""The composition root: builds a cell (session, index, supervisor, child workers) from config.

Nothing else constructs these; there are no module-level sessions or singletons.
"""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import threading
import time
from typing import Any

from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.recording.index import CycleIndex
from cellctl.supervisor.supervisor import Supervisor

__all__ = ["Cell", "WorkerProcesses", "build_cell", "load_identification", "preflight"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


def load_identification(cfg: CellConfig) -> tuple[Any, Any]:
    """The bin catalog and the identification function the identify step uses."""
    from cellctl.geometry.catalog import load_catalog
    from cellctl.vision import identify

    return identify, load_catalog(cfg.path(cfg.catalog))


def preflight(cfg: CellConfig) -> None:
    """What ``cellctl run`` needs beyond a well-formed config, checked before anything starts (``validate``
    runs the same): the state machines, the nozzle model, the hand–eye file, the bin catalog parsed as a
    catalog, ``sim.bin_type`` in it when a sim backend renders it. Endpoints are checked when the config
    is read (:mod:`cellctl.bus.endpoints`).

    Raises:
        ConfigError: one line naming the key and the value.
    """
    from cellctl.errors import ConfigError
    from cellctl.geometry.catalog import load_catalog
    from cellctl.supervisor.registry import load_definitions
    from cellctl.vision.handeye import configured_hand_eye
    from cellctl.washing.nozzle import NozzleModel

    load_definitions(cfg.root)
    # The checks across a model's fields that need the domain's models (cellctl.config imports none):
    try:
        NozzleModel.from_config(cfg.nozzle)
    except ConfigError as err:
        raise ConfigError(f"nozzle: {err}") from None
    configured_hand_eye(cfg)  # a bad calibration stops `validate`/`run`, not the first move
    try:
        catalog = load_catalog(cfg.path(cfg.catalog))  # as the identify step loads it (load_identification)
    except ConfigError as err:
        raise ConfigError(f"catalog: {err}") from None
    if "sim" in (cfg.robot.backend, cfg.camera.backend) and cfg.sim.bin_type not in catalog:
        raise ConfigError(
            f"sim.bin_type {cfg.sim.bin_type!r} is not in the catalog {str(cfg.path(cfg.catalog))!r};"
            f" expected one of {catalog.names}"
        )


def _die_with_parent() -> None:
    """Child side of fork: get SIGTERM when the daemon dies, even by SIGKILL (Linux only)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


class WorkerProcesses:
    """Child worker processes (``cellctl worker <role>``), stopped with SIGTERM then SIGKILL."""

    def __init__(self, cfg: CellConfig, config_file: str | None, overrides: list[str], roles: list[str]) -> None:
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.cfg = cfg
        base = [sys.executable, "-m", "cellctl", "worker"]
        extra: list[str] = []
        if config_file:
            extra += ["--config", str(config_file)]
        for ov in overrides:
            extra += ["--set", ov]
        self._cmds = {role: [*base, role, *extra] for role in roles}
        self._backoff: dict[str, float] = {}
        self._not_before: dict[str, float] = {}

    def start(self) -> None:
        for role, cmd in self._cmds.items():
            self.start_one(role, cmd)

    def restart_dead(self) -> list[str]:
        """Start again every child that exited, with a doubling back-off (1 s … 60 s) per role.

        The supervisor has already aborted the cycle when the worker's token went; this only
        brings the process back, so the operator's Clear → Reset → Start finds it alive. A
        frozen child is not dead and is left alone (it resumes by itself).
        """
        now = time.monotonic()
        restarted = []
        for role, p in list(self.procs.items()):
            code = p.poll()
            if code is None or now < self._not_before.get(role, 0.0):
                continue
            delay = min(60.0, 2 * self._backoff.get(role, 0.5))
            self._backoff[role] = delay
            self._not_before[role] = now + delay
            log.warning(
                "%s worker (pid %d) exited with %s; restarting it (next restart in >= %.0f s)", role, p.pid, code, delay
            )
            self.start_one(role)
            restarted.append(role)
        return restarted

    def start_one(self, role: str, cmd: list[str] | None = None) -> None:
        cmd = cmd or self._cmds[role]
        self.procs[role] = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, start_new_session=True, preexec_fn=_die_with_parent
        )
        log.info("started %s worker pid %d", role, self.procs[role].pid)

    def stop(self, timeout: float = 10.0) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for role, p in self.procs.items():
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s worker did not stop in %.0f s; killing", role, timeout)
                p.kill()
                p.wait()
        self.procs.clear()


class Cell:
    """A running cell: the daemon's router session, its supervisor and optional child workers."""

    def __init__(
        self, cfg: CellConfig, supervisor: Supervisor, session: Any, index: CycleIndex, workers: WorkerProcesses | None
    ) -> None:
        self.cfg = cfg
        self.supervisor = supervisor
        self.session = session
        self.index = index
        self.workers = workers

    def run(self, stop: threading.Event) -> None:
        """Serve until ``stop`` is set (SIGTERM/SIGINT in the daemon); restart child workers that died."""
        while not stop.wait(0.5):
            if self.workers is not None:
                self.workers.restart_dead()

    def close(self) -> None:
        try:
            self.supervisor.stop()
        finally:
            if self.workers is not None:
                self.workers.stop()
            self.index.close()
            self.session.close()

    def __enter__(self) -> Cell:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def build_cell(
    cfg: CellConfig,
    *,
    with_workers: bool = False,
    config_file: str | None = None,
    overrides: list[str] | None = None,
    identification: tuple[Any, Any] | None = None,
) -> Cell:
    """Open the router session, the cycle index and the supervisor; optionally start workers.

    Args:
        identification: ``(identify, catalog)`` to use instead of the vision module and the
            configured catalog (tests inject doubles here).

    Raises:
        ConfigError: the endpoints cannot be bound, or the state machines do not validate.
    """
    try:
        identify, catalog = identification or load_identification(cfg)
    except ImportError as err:
        log.warning("bin identification unavailable (%s); the identify step will fail with that reason", err)
        identify, catalog = None, None
    index = CycleIndex(cfg.path(cfg.recording.index))
    session = open_session(cfg, "router")
    try:
        sup = Supervisor(cfg, session, index, identify=identify, catalog=catalog)
        sup.start()
    except Exception:
        session.close()
        index.close()
        raise
    workers = None
    if with_workers:
        workers = WorkerProcesses(cfg, config_file, overrides or [], cfg.supervisor.spawn_workers)
        workers.start()
    return Cell(cfg, sup, session, index, workers)
