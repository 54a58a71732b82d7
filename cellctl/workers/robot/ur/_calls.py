"""Bounded sending calls on ur-rtde's control interface, and the errors that say how one ended.

ur-rtde's interfaces are not thread-safe: every call goes through the robot's one ``io`` lock.
A call that *sends* on the control interface (``moveJ``, ``stopJ``, ``kickWatchdog``, …) can block
for good once its link died (ur-rtde then reconnects inside the call), so those run on a call
thread of their own (:class:`CallThread`) and are waited for with a bound; one that overruns marks
that interface *wedged*: it is abandoned (disconnected on a throw-away thread, :func:`dispose`),
never called again, and the operator's ``clear_fault`` connects fresh interfaces. Reads are cache
reads and never block.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["T_CMD", "T_KICK", "T_PATH", "CallThread", "Late", "Refused", "Wedged", "dispose"]


class Wedged(RuntimeError):
    """A control call overran its bound: the interface is given up (a RuntimeError like ur-rtde's)."""


class Late(RuntimeError):
    """A call that may overrun (a watchdog kick on a loaded machine) did: nothing is given up."""


class CallThread:
    """Runs one interface's sending calls in order on a daemon thread; each caller waits with a bound.

    Daemon, not a ``ThreadPoolExecutor``: a call stuck in ur-rtde must not hold up the worker's exit.
    """

    def __init__(self, name: str) -> None:
        self.wedged: str | None = None
        self.busy = False
        """A call is queued or running (a late one that was not fatal may still be)."""
        self.closed = False
        """Its interface is given up or replaced: calls still queued are dropped, not run."""
        self._q: queue.SimpleQueue[tuple[Callable[..., Any], tuple[Any, ...], threading.Event, list[Any]] | None]
        self._q = queue.SimpleQueue()
        threading.Thread(target=self._run, name=name, daemon=True).start()

    def _run(self) -> None:
        while (item := self._q.get()) is not None:
            fn, args, done, box = item
            if self.closed:
                # a call queued behind one that wedged (or behind the interface's replacement) must not
                # run later on the old interface: ur-rtde would reconnect it inside the call and restart
                # the control program under the fresh interface's motion
                box.append((False, Wedged(f"{getattr(fn, '__name__', 'call')} dropped: the interface was given up")))
                done.set()
                continue
            try:
                box.append((True, fn(*args)))
            except Exception as err:  # handed to the caller
                box.append((False, err))
            self.busy = False
            done.set()

    def call(self, timeout_s: float, fn: Callable[..., Any], *args: Any, fatal: bool = True) -> Any:
        """``fn(*args)`` on the call thread, waited for ``timeout_s``.

        Raises:
            Wedged: the interface was given up, or (``fatal``) this call overran: it is given up now.
            Late: a call that is not ``fatal`` overran (it may still finish; nothing is given up).
        """
        if self.wedged is not None or self.closed:
            raise Wedged(self.wedged or "the interface was replaced")
        done: threading.Event = threading.Event()
        box: list[Any] = []
        self.busy = True
        self._q.put((fn, args, done, box))
        if not done.wait(timeout_s):
            late = f"{getattr(fn, '__name__', 'call')} did not return within {timeout_s:g} s"
            if not fatal:
                raise Late(late)
            self.wedged = late
            self.close()
            raise Wedged(self.wedged)
        ok, value = box[0]
        if ok:
            return value
        raise value

    def close(self) -> None:
        self.closed = True
        self._q.put(None)


T_KICK = 1.0
T_CMD = 5.0
T_PATH = 15.0
"""Bounds (s) of control calls: a watchdog kick, a stop/setting, a path (stop, upload, start, command).
Generous: a dead link is noticed by the receive side (disconnected, or no data for data_stale_ms); the
bounds only keep a wedged call from holding the lock, and a 0.5 s kick bound overran under a load
average of 10 on 2 cores (the demo's only false fault)."""


def dispose(*handles: Any) -> None:
    """Disconnect given-up interfaces on a throw-away thread (a wedged one may block in there)."""

    def run() -> None:
        for h in handles:
            if h is not None:
                try:
                    h.disconnect()
                except RuntimeError:
                    pass

    t = threading.Thread(target=run, name="ur-dispose", daemon=True)
    t.start()
    t.join(2.0)


class Refused(Exception):
    """A connection refusal that retrying will not fix (wrong model, mode, local control)."""
