"""The state one whole-bin plan's stages share, and a candidate station's evaluation.

:func:`cellctl.planning.whole.plan_whole` is a sequence of module-level stages over one
:class:`WholeState`: each stage reads what earlier ones filled in and fills its own part (the
fields are grouped by the stage that sets them). The stations' evaluations and tours run on
forked workers (:func:`cellctl.planning.parallel.fork_map`), which inherit the state as it is.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh, BinType
from cellctl.planning.plan import PlanParams
from cellctl.planning.raycast import RayCaster
from cellctl.planning.robot import RobotModel
from cellctl.planning.stations import Candidate
from cellctl.planning.whole.connection import Connected
from cellctl.planning.whole.records import ProgressFn, SurfaceSummary, WholeParams

__all__ = ["StationEval", "WholeState"]


@dataclass
class StationEval:
    """One candidate station evaluated: per surface its set-up, filtered and reached viewpoints,
    visibility, seen faces and connection; its identification pose."""

    cand: Candidate
    setups: dict[str, Any] = field(default_factory=dict)
    filt: dict[str, Any] = field(default_factory=dict)
    found: dict[str, Any] = field(default_factory=dict)
    vis: dict[str, Any] = field(default_factory=dict)
    seen: dict[str, NDArray[np.bool_]] = field(default_factory=dict)
    con: dict[str, Connected] = field(default_factory=dict)
    identify: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
    replaced: int = 0
    unconnected: int = 0
    accept: Callable[[int, NDArray[np.float64]], bool] | None = None
    margin: float = 0.0
    """The clearance this station's configurations keep (the plan's, + odometry error without a board)."""
    identify_reason: str | None = None


@dataclass
class WholeState:
    """What the stages of one whole-bin plan share (see the module docstring).

    Attributes (by the stage that sets them):
        mesh, params, robot, bin_type, progress, job_id, workers: the request.
        t0, cpu0, ru0, times: the clocks and seconds per stage.
        step, q_home, head, cands, usable, rays: the set-up (:func:`~cellctl.planning.whole.pipeline.start`).
        surfaces, shared, counts: per surface the filtered viewpoints and the upper bound
            (:func:`~cellctl.planning.whole.pipeline.bound_surfaces`); ``shared[surf]`` is
            ``(filtered, surface faces, the surface's random stream)``.
        areas, bounds, evals, scores, chosen_ev: the evaluated and chosen stations
            (:mod:`~cellctl.planning.whole.evaluation`).
        floors, picked, greedy_n, sel_counts: the viewpoint selection per chosen station
            (:mod:`~cellctl.planning.whole.selection`); the budget may change them.
        cols, offs, off, must_now: the exact (station, viewpoint) cover's columns and rows.
        per_vp, half_turn, snap, station_covers, res, exact: the tours (:mod:`~cellctl.planning.whole.tours`);
            ``res`` is the tour run kept.
    """

    mesh: BinMesh
    params: WholeParams
    robot: RobotModel
    bin_type: BinType | None
    progress: ProgressFn | None
    job_id: str | None
    workers: int
    t0: float
    cpu0: float
    ru0: Any
    step: float
    q_home: NDArray[np.float64]
    head: dict[str, Any]
    cands: list[Candidate]
    usable: list[Candidate]
    rays: RayCaster
    times: dict[str, float] = field(default_factory=dict)
    surfaces: dict[str, SurfaceSummary] = field(default_factory=dict)
    shared: dict[str, tuple[Any, NDArray[np.int64], np.random.Generator]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    areas: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    bounds: dict[str, float] = field(default_factory=dict)
    evals: list[StationEval] = field(default_factory=list)
    scores: dict[str, float] = field(default_factory=dict)
    chosen_ev: list[StationEval] = field(default_factory=list)
    floors: dict[str, float] = field(default_factory=dict)
    picked: dict[str, list[NDArray[np.int64]]] = field(default_factory=dict)
    greedy_n: dict[str, int] = field(default_factory=dict)
    sel_counts: dict[str, int] = field(default_factory=dict)
    cols: list[tuple[int, NDArray[np.bool_]]] = field(default_factory=list)
    offs: dict[str, int] = field(default_factory=dict)
    off: int = 0
    must_now: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    per_vp: float = 0.0
    half_turn: bool = False
    snap: dict[tuple[int, str], tuple[Any, Any, Any]] = field(default_factory=dict)
    station_covers: dict[tuple[int, str], Any] = field(default_factory=dict)
    res: dict[str, Any] = field(default_factory=dict)
    exact: Any = None

    @property
    def p0(self) -> PlanParams:
        """The single-station parameters every station's plans start from."""
        return self.params.plan

    def tick(self, key: str, since: float) -> float:
        """Book the seconds since ``since`` under ``key``; the time now."""
        now = time.perf_counter()
        self.times[key] = self.times.get(key, 0.0) + now - since
        return now

    def say(self, stage: str, frac: float, msg: str = "") -> None:
        if self.progress:
            self.progress(stage, frac, msg)

    def close_times(self) -> dict[str, float]:
        """``times`` with the total and the CPU seconds (the figure a shared machine does not inflate)."""
        self.times["total"] = time.perf_counter() - self.t0
        self.times.update(_cpu_s(self.cpu0, self.ru0))
        return self.times


def _cpu_s(cpu0: float, ru0: Any) -> dict[str, float]:
    """CPU seconds since ``cpu0`` / ``ru0``: ``cpu`` this process and its finished workers together,
    ``cpu_workers`` the workers' share (user + system)."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    kids = (ru.ru_utime - ru0.ru_utime) + (ru.ru_stime - ru0.ru_stime)
    return {"cpu": time.process_time() - cpu0 + kids, "cpu_workers": kids}
