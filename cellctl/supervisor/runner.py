"""The work of an acting state on its own short-lived thread, reported back as a :class:`StepDone`.

Any state change cancels the running activation (a new token), so a Stop/Abort/Hold is acted on
at once even while a robot move is in flight; a late report of a cancelled activation carries
a stale token and is ignored by the dispatcher.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable

from cellctl.errors import CellError
from cellctl.supervisor.context import Cancelled, CycleContext, StepRun
from cellctl.supervisor.events import StepDone
from cellctl.supervisor.steps import Step

__all__ = ["Runner", "run_step"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

Work = Callable[[StepRun], str | None]


def run_step(step: type[Step], run: StepRun) -> str:
    """Run one step, adding its wall time to ``ctx.step_seconds[run.name]`` (the cycle state's name)."""
    t0 = time.perf_counter()
    try:
        return step()(run)
    finally:
        sec = run.ctx.step_seconds
        sec[run.name] = sec.get(run.name, 0.0) + time.perf_counter() - t0


class Runner:
    """Launches activations and keeps the token of the current one.

    Args:
        done: receives each activation's :class:`StepDone` (puts it on the dispatcher's queue).
    """

    def __init__(self, done: Callable[[StepDone], None]) -> None:
        self._done = done
        self._tokens = itertools.count(1)
        self.token = 0
        self.active: StepRun | None = None

    def cancel(self) -> None:
        """Cancel the running activation, if any; whatever it reports later is stale."""
        if self.active is not None:
            self.active.cancelled.set()
            self.active = None
        self.token = next(self._tokens)

    def finished(self, ev: StepDone) -> bool:
        """True when ``ev`` reports the current activation (which then is no longer active)."""
        if ev.token != self.token:
            return False
        self.active = None
        return True

    def launch(self, name: str, ctx: CycleContext, work: Work) -> StepRun:
        """Start ``work`` on a thread under the current token; a CellError becomes outcome ``failed``."""
        run = StepRun(ctx, self.token, name)
        self.active = run

        def body() -> None:
            try:
                outcome = work(run)
                self._done(StepDone(run.token, outcome))
            except Cancelled:
                pass
            except CellError as err:
                self._done(StepDone(run.token, "failed", str(err)))
            except Exception as err:
                log.exception("%s crashed", name)
                self._done(StepDone(run.token, "failed", f"internal error in {name}: {type(err).__name__}: {err}"))

        threading.Thread(target=body, name=f"run-{name}", daemon=True).start()
        return run
