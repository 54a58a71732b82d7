"""The step contract: a class per cycle state with declared outcomes and declared blackboard fields."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

from cellctl.supervisor.context import StepRun
from cellctl.supervisor.context.view import Declared, check_declared, seen_by

__all__ = ["AT_STATION", "Step"]

AT_STATION = (
    "stations.planned",
    "stations.station_order",
    "stations.station_index",
    "stations.surface_index",
)
"""What ``ctx.stations.current_station()`` and ``ctx.surface`` read (the station loop's place): a step
that asks where the cycle is CONSULTS these (a single-station cycle has no stations)."""


class Step(ABC):
    """One state of the inspection cycle.

    A step declares every outcome it can return in ``OUTCOMES``; ``states/cycle.yaml`` must
    map each of them. It declares the blackboard fields (``record.field`` of the
    :class:`~cellctl.supervisor.context.CycleContext`'s sub-records) it ``READS`` (needs set: the
    loader checks a step writes them on every path before it), ``CONSULTS`` (uses when set, and
    copes with None or empty itself: not checked by the loader) and ``WRITES``. ``execute`` gets
    ``run.ctx`` as a :class:`~cellctl.supervisor.context.view.StepView` that raises
    :class:`~cellctl.errors.UndeclaredAccess` on anything else. Mutating a list or dict field
    (``append``, ``pop``, item assignment) reads and writes it: declare it in ``READS`` or ``CONSULTS``
    and in ``WRITES``. A field the step assigned itself in the same activation may be read back
    without a declaration. ``execute`` runs on a step thread, never on the dispatcher; it raises a
    CellError to fail (the runner turns that into outcome ``failed`` with the reason).
    """

    NAME: ClassVar[str]
    OUTCOMES: ClassVar[tuple[str, ...]]
    DESCRIPTION: ClassVar[str] = ""
    READS: ClassVar[tuple[str, ...]] = ()
    """Blackboard fields this step needs set (FlexBE input keys); the loader checks a writer precedes it."""
    CONSULTS: ClassVar[tuple[str, ...]] = ()
    """Blackboard fields this step uses when they are set (optional input keys); the loader does not check them."""
    WRITES: ClassVar[tuple[str, ...]] = ()
    """Blackboard fields this step sets for the steps after it (output keys)."""

    def __init_subclass__(cls, **kw: Any) -> None:
        super().__init_subclass__(**kw)
        check_declared(getattr(cls, "NAME", cls.__name__), READS=cls.READS, CONSULTS=cls.CONSULTS, WRITES=cls.WRITES)

    @classmethod
    def declared(cls) -> Declared:
        return Declared(cls.NAME, cls.READS, cls.CONSULTS, cls.WRITES)

    @abstractmethod
    def execute(self, run: StepRun) -> str:
        """Do the step's work and return one of ``OUTCOMES``."""

    def __call__(self, run: StepRun) -> str:
        outcome = self.execute(seen_by(run, self.declared()))
        if outcome not in self.OUTCOMES:
            raise ValueError(
                f"outcome {outcome!r} does not belong to the outcomes of step {self.NAME!r}: {self.OUTCOMES}"
            )
        return outcome
