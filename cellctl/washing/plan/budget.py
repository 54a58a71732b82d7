"""A wash plan's CPU ceiling (``WashParams.cpu_budget_s``): the measured rate that predicts whether one
more station's reachability fits, and the budget as one station sees it."""

from __future__ import annotations

from dataclasses import dataclass

__all__: list[str] = []


class _CpuRate:
    """CPU seconds per pose and roll through reachability (IK, collision checks: 80-95 % of a wash
    plan's CPU), measured on the stations planned so far: predicts whether one more station's
    reachability fits the plan's budget (``WashParams.cpu_budget_s``).

    Counted where the cost is: a station's filtered poses times the rolls tried, known just before
    its reachability runs. A station's waypoints in reach (the previous unit) mispredicted the
    residue pass by 5x (52 residue points, 5.7 s: 1177 poses x 12 rolls) and a mixed bin's round
    reached 10.4 s. The rest of a station (filters, cover, tour) is not predicted: the budget's
    margin below the 10 s target holds it.
    """

    def __init__(self, budget_s: float, prior: float = 0.0, first_free: bool = True) -> None:
        self.budget_s, self.prior, self.first_free = budget_s, prior, first_free
        self.cpu_s, self.units = 0.0, 0

    def per_unit(self) -> float:
        return self.cpu_s / self.units if self.units else self.prior

    def add(self, units: int, cpu_s: float) -> None:
        self.cpu_s += cpu_s
        self.units += units

    def predict(self, units: int) -> float:
        return units * self.per_unit()

    def fits(self, units: int, spent_s: float) -> bool:
        """Whether ``units`` more fit after ``spent_s`` (before anything is measured: the plan's first station)."""
        if self.first_free and not self.units:
            return True
        return spent_s + self.predict(units) <= self.budget_s


@dataclass
class _Budget:
    """A plan's CPU ceiling as one station sees it: the shared rate, the plan's CPU clock start, and
    the ``counts`` key a station skipped for it goes under."""

    rate: _CpuRate
    cpu0: float
    key: str
