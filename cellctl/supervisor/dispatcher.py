"""The dispatcher thread: typed events (:mod:`.events`) taken one at a time, in order, a beat when quiet.

Every decision of the supervisor happens on this one thread, so its state needs no locks; Zenoh
callbacks and activation threads only put events. A bug in one event is logged and the thread goes on.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Self

from cellctl.supervisor import events

__all__ = ["Dispatcher"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class Dispatcher:
    """Owns the event queue and the thread that drains it (the supervisor is one).

    Subclasses implement :meth:`start`/:meth:`stop` (around :meth:`_start_dispatcher` /
    :meth:`_stop_dispatcher`), :meth:`_dispatch` (one event), :meth:`_beat` (no event for a
    period) and :meth:`_shutdown` (the Shutdown event, the thread's last work).
    """

    def __init__(self, period_s: float) -> None:
        self._events: queue.Queue[events.DispatchEvent] = queue.Queue()
        self._period_s = period_s
        self._thread: threading.Thread | None = None
        self._stopped = threading.Event()

    def start(self) -> None:
        raise NotImplementedError

    def stop(self, timeout: float = 10.0) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def wait_stopped(self, timeout: float | None = None) -> bool:
        return self._stopped.wait(timeout)

    def _start_dispatcher(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="dispatcher", daemon=True)
        self._thread.start()

    def _stop_dispatcher(self, timeout: float) -> bool:
        """Put Shutdown and wait for the thread; False when it was not running."""
        if self._thread is None:
            return False
        self._events.put(events.Shutdown())
        self._thread.join(timeout)
        self._thread = None
        return True

    def _dispatch(self, ev: events.DispatchEvent) -> None:
        raise NotImplementedError

    def _beat(self) -> None:
        raise NotImplementedError

    def _shutdown(self) -> None:
        raise NotImplementedError

    def _loop(self) -> None:
        next_beat = time.monotonic() + self._period_s
        while True:
            try:
                ev = self._events.get(timeout=max(0.0, next_beat - time.monotonic()))
            except queue.Empty:
                self._beat()
                next_beat = time.monotonic() + self._period_s
                continue
            try:
                if isinstance(ev, events.Shutdown):
                    self._shutdown()
                    self._stopped.set()
                    return
                self._dispatch(ev)
            except Exception:  # the dispatcher must survive any bug in one event
                log.exception("dispatcher failed on %s", type(ev).__name__)
