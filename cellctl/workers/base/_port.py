"""The Base interface and its ``sim`` and ``manual`` backends."""

from __future__ import annotations

import abc
import threading
import time
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from cellctl.config import CellConfig
from cellctl.errors import ConfigError, RobotError

__all__ = ["Base", "BaseState", "ManualBase", "SimBase", "make_base"]


@dataclass(frozen=True)
class BaseState:
    """Where the base is: parked at ``station`` (or not), moving, and what its driver says."""

    station: int | None
    parked: bool
    moving: bool
    detail: str = ""


class Base(abc.ABC):
    """A mobile base that parks the arm beside the bin at numbered stations."""

    NEEDS_CONFIRMATION: ClassVar[bool] = False
    """True when a person or the PLC parks it and confirms (``base_parked`` command): the cycle says so."""

    @abc.abstractmethod
    def park(self, station: int) -> BaseState:
        """Drive to and park at ``station``; blocks. Raises RobotError (stopped, timeout, refused)."""

    @abc.abstractmethod
    def state(self) -> BaseState:
        """Now (never blocks)."""

    @abc.abstractmethod
    def stop(self, reason: str) -> None:
        """Stop driving now; a park in progress raises RobotError."""

    def pose(self) -> NDArray[np.float64] | None:
        """Where the base says it is parked, ``T_map_base`` (4, 4) in its map frame, or None: it reports none.

        A vendor AMR's driver returns its localisation here; the cycle carries the bin pose measured
        at an earlier station through it to a station that cannot see the board (``base_odometry``).
        The ``sim`` base's report comes with the robot worker's approach reply (the twin parks it).
        """
        return None

    def confirm(self, station: int) -> None:
        """A person or the PLC says the base is parked at ``station`` (bases with ``NEEDS_CONFIRMATION``).

        Raises:
            RobotError: this base parks by itself, or the confirmation changes nothing.
        """
        raise RobotError(f"base confirmed parked at station {station}, but this base parks by itself")


def _check_station(station: int) -> int:
    if not isinstance(station, int) or station < 0:
        raise RobotError(f"station is {station!r}; expected a station number >= 0")
    return station


class SimBase(Base):
    """The twin's base: parking takes ``drive_s`` of (scaled) time, then it is parked."""

    def __init__(self, drive_s: float = 4.0) -> None:
        self.drive_s = drive_s
        self._stop = threading.Event()
        self._reason = ""
        self._state = BaseState(None, False, False, "sim")

    def park(self, station: int) -> BaseState:
        k = _check_station(station)
        self._stop.clear()
        self._state = BaseState(None, False, True, f"driving to station {k}")
        if self._stop.wait(self.drive_s):
            self._state = BaseState(None, False, False, f"stopped: {self._reason}")
            raise RobotError(f"parking at station {k} stopped ({self._reason})")
        self._state = BaseState(k, True, False, "sim")
        return self._state

    def state(self) -> BaseState:
        return self._state

    def stop(self, reason: str) -> None:
        self._reason = reason
        self._stop.set()


class ManualBase(Base):
    """An operator or the PLC parks the base and confirms (:meth:`confirm`, fed from the command topic/OPC UA);
    :meth:`park` waits for that confirmation up to ``timeout_s``."""

    NEEDS_CONFIRMATION = True

    def __init__(self, timeout_s: float = 300.0) -> None:
        self.timeout_s = timeout_s
        self._cv = threading.Condition()
        self._confirmed: int | None = None
        self._stopped: str | None = None
        self._waiting: int | None = None

    def confirm(self, station: int) -> None:
        """The operator/PLC says the base is parked at ``station``.

        Raises:
            RobotError: no park is awaited, or another station is (the confirmation changes nothing).
        """
        k = _check_station(station)
        with self._cv:
            if self._waiting is None:
                raise RobotError(f"base confirmed parked at station {k}, but the cell is not waiting for the base")
            if self._waiting != k:
                raise RobotError(
                    f"base confirmed parked at station {k}, but the cell waits for station {self._waiting}"
                )
            self._confirmed = k
            self._cv.notify_all()

    @property
    def waiting(self) -> int | None:
        """The station a park waits to be confirmed at, or None."""
        with self._cv:
            return self._waiting

    def park(self, station: int) -> BaseState:
        k = _check_station(station)
        deadline = time.monotonic() + self.timeout_s
        with self._cv:
            self._confirmed, self._stopped, self._waiting = None, None, k
            try:
                while self._confirmed != k:
                    if self._stopped is not None:
                        raise RobotError(f"waiting for the base at station {k} stopped ({self._stopped})")
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise RobotError(
                            f"the base was not confirmed parked at station {k} within {self.timeout_s:g} s "
                            "(base.confirm_timeout_s)"
                        )
                    self._cv.wait(left)
            finally:
                self._waiting = None
        return self.state()

    def state(self) -> BaseState:
        with self._cv:
            if self._waiting is not None:
                return BaseState(None, False, False, f"waiting for the operator to park at station {self._waiting}")
            return BaseState(self._confirmed, self._confirmed is not None, False, "manual")

    def stop(self, reason: str) -> None:
        with self._cv:
            self._stopped = reason
            self._cv.notify_all()


def make_base(cfg: CellConfig) -> Base:
    """The ``base.backend`` of ``cfg``, as the supervisor's approaching step drives it.

    ``sim``: the twin's base; the drive itself is modelled by the sim/UR robot worker when it
    parks (ApproachRequest.park, ``DRIVE_S / robot.speed_scale``), so this side does not wait
    again. ``manual``: waits for the operator's/PLC's ``base_parked`` command.

    Raises:
        ConfigError: an unknown backend.
    """
    name = cfg.base.backend
    if name == "sim":
        return SimBase(0.0)
    if name == "manual":
        return ManualBase(cfg.base.confirm_timeout_s)
    raise ConfigError(f"base backend {name!r} is unknown; expected one of ['sim', 'manual']")
