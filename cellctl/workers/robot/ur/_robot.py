"""The ``ur`` backend of the robot role, composed of its layers (connection → safety → motion, maintenance)."""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.config import CellConfig
from cellctl.geometry.catalog import Catalog
from cellctl.messages import FaultReport, RobotState
from cellctl.workers.robot.ur._calls import T_CMD, CallThread
from cellctl.workers.robot.ur._maintenance import UrMaintenance
from cellctl.workers.robot.ur._motion import UrMotion

__all__ = ["UrRobot"]


class UrRobot(UrMaintenance, UrMotion):
    """The ``ur`` backend of the robot role.

    Args:
        cfg: cell config (``robot.ur`` for the controller; ``sim`` for the cell layout).
        catalog: an already loaded catalog.
        on_change: called after the joints or the scenario changed.
        on_fault: called with the :class:`~cellctl.messages.FaultReport` of a fault when one is
            latched (``active``), and when the operator cleared it (not ``active``); the worker
            publishes it and withdraws/redeclares its liveliness token.

    Raises:
        RobotError: the controller is unreachable, not a UR10e, in local control, not RUNNING
            (the mode is named), safety-stopped, or refuses ur-rtde's recipes.
    """

    def __init__(
        self,
        cfg: CellConfig,
        catalog: Catalog | None = None,
        on_change: Callable[[], None] | None = None,
        on_fault: Callable[[FaultReport], None] | None = None,
    ) -> None:
        self.io = threading.Lock()
        """The one lock around every ur-rtde call (its interfaces are not thread-safe)."""
        self.ur = cfg.robot.ur
        self.on_fault = on_fault
        self._c: Any = None
        self._r: Any = None
        self._d: Any = None
        self._calls = CallThread("ur-control-calls")
        self._fault: str | None = None
        self.fault_report: FaultReport | None = None
        """The latched fault, typed (condition, robot and safety mode, safety bits), until cleared."""
        self._last_state: dict[str, Any] | None = None
        self._motion_seq = 0
        """Counts motions sent: a stop meant for one motion never reaches a later one."""
        self._fault_motion = -1
        """The motion the latched fault's stopJ is for."""
        self._q_meas: NDArray[np.float64] | None = None
        self._tcp: NDArray[np.float64] | None = None
        self._ts = -1.0
        self._data_t = time.monotonic()
        self._runtime = 0
        self.speed_slider: float | None = None
        self.tracking: deque[float] = deque(maxlen=100_000)
        """Path deviation (rad) of every sample during motions (``cellctl bench ur``)."""
        self.fault_log: list[tuple[float, str]] = []
        """(monotonic time, text) of every latched fault."""
        super().__init__(cfg, catalog, on_change)
        self._connect()
        self._monitor_stop = threading.Event()
        self._monitor = threading.Thread(target=self._watch, name="ur-safety-monitor", daemon=True)
        self._monitor.start()
        self._kicker = threading.Thread(target=self._kick_loop, name="ur-watchdog-kick", daemon=True)
        self._kicker.start()

    def _accel_fraction(self) -> float:
        return self.ur.accel_fraction

    @property
    def publishes_twin(self) -> bool:
        """Against the emulator, this worker publishes the twin's SimState with the arm's RTDE joints."""
        return self.ur.twin

    def close(self) -> None:
        if hasattr(self, "_monitor_stop"):
            self._monitor_stop.set()
            self._monitor.join(timeout=1.0)
            self._kicker.join(timeout=1.0)
        self._stopj()
        with self.io:
            if self._linked():
                try:
                    self._send(T_CMD, self._c.stopScript)  # a clean end, not a watchdog expiry
                except RuntimeError:
                    pass
        self._disconnect()
        super().close()

    def state(self) -> RobotState:
        st = super().state()
        return st.model_copy(update={"speed_slider": self.speed_slider, "fault": self._fault})
