"""The mobile Base interface: sim and manual backends (park at station k, state, stop, timeout)."""

from __future__ import annotations

import threading
import time

import pytest

from cellctl.config import load_config
from cellctl.errors import RobotError
from cellctl.workers.base import ManualBase, SimBase, make_base


def test_sim_base_parks_and_a_stop_interrupts_it() -> None:
    b = SimBase(0.05)
    assert b.park(2).station == 2 and b.state().parked
    slow = SimBase(5.0)
    threading.Timer(0.1, slow.stop, ("operator stop",)).start()
    with pytest.raises(RobotError, match=r"parking at station 1 stopped \(operator stop\)"):
        slow.park(1)
    assert not slow.state().parked


def test_manual_base_waits_for_the_confirmation_of_that_station() -> None:
    b = ManualBase(timeout_s=5.0)
    with pytest.raises(RobotError, match="not waiting for the base"):
        b.confirm(3)  # before the cell asks: refused, not remembered
    wrong: list[str] = []

    def confirm_wrong() -> None:
        try:
            b.confirm(0)
        except RobotError as err:
            wrong.append(str(err))

    threading.Timer(0.05, confirm_wrong).start()  # the wrong station does not count
    threading.Timer(0.2, b.confirm, (3,)).start()
    t0 = time.monotonic()
    st = b.park(3)
    assert st.station == 3 and st.parked and time.monotonic() - t0 >= 0.15
    assert wrong == ["base confirmed parked at station 0, but the cell waits for station 3"]


def test_manual_base_times_out_naming_the_station_and_the_setting() -> None:
    with pytest.raises(RobotError, match=r"not confirmed parked at station 4 within 0.1 s \(base.confirm_timeout_s\)"):
        ManualBase(timeout_s=0.1).park(4)


def test_bad_station_and_backend_choice() -> None:
    with pytest.raises(RobotError, match="station is -1"):
        SimBase(0.0).park(-1)
    assert isinstance(make_base(load_config(None, ["base.backend=manual"])), ManualBase)
    assert isinstance(make_base(load_config(None, [])), SimBase)
