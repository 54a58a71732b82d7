"""Whole-bin plan records and the plan file: parameters, the timing model, stations, the plan.

:class:`WholeParams` (with its :class:`TimingModel`) is what :func:`cellctl.planning.whole.plan_whole`
is asked; :class:`WholePlan` (ordered :class:`StationPlan` s, per-surface :class:`SurfaceSummary`)
is what it answers. :func:`write_whole` / :func:`read_whole` put a plan in the plan cache: every
station's per-surface plan as an ordinary plan file, and the whole plan's record beside them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import PlanningError
from cellctl.planning.plan import Plan, PlanParams
from cellctl.planning.stations import Candidate, StationCover, StationParams
from cellctl.surface import SURFACES

__all__ = [
    "WHOLE_FORMAT",
    "ProgressFn",
    "StationPlan",
    "SurfaceSummary",
    "TimingModel",
    "WholeParams",
    "WholePlan",
    "read_whole",
    "whole_path",
    "write_whole",
]

WHOLE_FORMAT = "cellctl-whole-plan/1"

ProgressFn = Callable[[str, float, str], None]


@dataclass(frozen=True)
class TimingModel:
    """The modelled cycle's time parts.

    Attributes:
        settle_s: wait after each arrival before the capture. The issue's target uses 0.5 s
            (the paper's robot needed 1 s); the sim arm's own settle is ``robot.settle_s``.
        capture_s: one capture.
        speed_fraction: fraction of the UR10e joint velocity limits (``robot.speed_fraction``).
        accel_fraction: fraction of the nominal joint accelerations
            (:data:`cellctl.motion.UR10E`, ``robot.ur.accel_fraction`` on the UR backend): the arm moves this way.
    """

    settle_s: float = 0.5
    capture_s: float = 0.1
    speed_fraction: float = 0.5
    accel_fraction: float = 1.0

    def motion_s(self, path: NDArray[np.float64]) -> float:
        """Seconds to move along ``path`` (K, 6), rest to rest at each waypoint."""
        from cellctl.motion import UR10E, time_parametrize

        if len(path) < 2:
            return 0.0
        return float(time_parametrize(path, UR10E, self.speed_fraction, self.accel_fraction).duration)


@dataclass(frozen=True)
class WholeParams:
    """Parameters of a whole-bin plan: the single-station ones (surface ignored), stations, timing."""

    plan: PlanParams = field(default_factory=PlanParams)
    stations: StationParams = field(default_factory=StationParams)
    timing: TimingModel = field(default_factory=TimingModel)
    surfaces: tuple[str, ...] = SURFACES
    exact_time_limit_s: float = 5.0
    view_min_gain_pct: float = 0.15
    """A viewpoint must add this % of its surface's upper bound to Greedy Area's set (0: all)."""
    estimate_thin: int = 1
    """> 1: rank candidate stations on every estimate_thin-th seed direction and evaluate in full only
    the chosen ones ± one station (about half the planning CPU). 1 (default): every candidate in full.
    Off by default: on case-study seeds 1 and 2 it chose 3 stations where the full evaluation takes 4,
    and external coverage fell to 89.5 / 87.0 % of the bound (target ≥ 90 %)."""
    chains: str = "needed"
    """"needed" (default): a selected viewpoint's chain home is visited only where its tour needs it
    (:func:`_with_needed_ancestors`), and the selection makes up what the chain viewpoints left out
    saw (:func:`_needed_and_made_up`): case study seed 0, 99 → 80 viewpoints, modelled cycle
    192 → 173 s, 92.3 → 92.0 % of the external bound. "all": every chain is visited."""
    min_bound_pct: dict[str, float] = field(default_factory=lambda: {"external": 91.0, "internal": 86.0})
    """Per surface, the % of its upper bound the selection must see (0 / absent: no floor): below it
    viewpoints are added past the gain rule (:func:`_fill_to_floor`); ``planner.whole.min_bound_pct``."""
    workers: int = 0
    """Processes one plan evaluates its candidate stations on (and runs the exact cover beside the
    tours): 0 (default) = the cores this process may use, 1 = in process. The plan is the same
    for any number (each candidate's evaluation reads only the shared set-up)."""
    cycle_budget_s: float = 0.0
    """The plant's takt for one bin's modelled cycle (s; 0: none; ``planner.whole.cycle_budget_s``,
    180). A plan above it takes one station fewer where that set still sees every surface's floor
    (``min_bound_pct``), then gives up the viewpoints that see least per modelled second while the
    floors hold (:func:`_trim_to_budget`); a plan within it is not touched."""
    odometry_m: float = 0.0
    """Bin-pose error left at a station that cannot see the board (the cycle carries the pose measured
    at an earlier station through the base's reported motion: two localisation reports, the yaw's
    lever): the extra clearance its configurations keep from the bin (0: none; a cell's config:
    ``planner.whole.odometry_error_m``, 10 mm)."""

    @classmethod
    def from_config(
        cls, whole: Any, plan: PlanParams, speed_fraction: float, accel_fraction: float = 1.0
    ) -> WholeParams:
        """From the config's ``planner.whole`` section (:class:`cellctl.config.WholeBinConfig`).

        ``speed_fraction`` and ``accel_fraction`` are the arm's (``robot.speed_fraction``,
        ``robot.ur.accel_fraction`` on the UR backend, else 1): the modelled cycle moves as the arm does.
        """
        return cls(
            plan=plan,
            stations=StationParams(
                candidates=whole.candidates,
                park_distance_m=whole.park_distance_m,
                max_stations=whole.max_stations,
                min_gain_pct=whole.min_station_gain_pct,
                cabin_half_m=tuple(whole.cabin_half_m),
                bin_in_cabin=tuple(whole.bin_in_cabin),
                allowed_deg=None if whole.allowed_deg is None else tuple(whole.allowed_deg),
                base_speed_m_s=whole.base_speed_m_s,
                base_turn_deg_s=whole.base_turn_deg_s,
                park_s=whole.park_s,
                inner_candidates=whole.inner_candidates,
                inner_park_distance_m=whole.inner_park_distance_m,
            ),
            timing=TimingModel(
                settle_s=whole.settle_s,
                capture_s=whole.capture_s,
                speed_fraction=speed_fraction,
                accel_fraction=accel_fraction,
            ),
            view_min_gain_pct=whole.view_min_gain_pct,
            odometry_m=whole.odometry_error_m,
            chains=whole.chains,
            min_bound_pct=dict(whole.min_bound_pct),
            cycle_budget_s=whole.cycle_budget_s,
        )

    @classmethod
    def for_cell(cls, cfg: Any, plan: PlanParams) -> WholeParams:
        """From a whole cell config: ``planner.whole`` and the arm's own motion limits
        (:func:`cellctl.motion.arm_fractions`: ``robot.speed_fraction``, and
        ``robot.ur.accel_fraction`` on the UR backend). ``cellctl plan --whole``, the planner
        worker and the bench all build their parameters here."""
        from cellctl.motion import arm_fractions

        return cls.from_config(cfg.planner.whole, plan, *arm_fractions(cfg.robot))

    def check(self) -> None:
        self.plan.check()
        self.stations.check()
        if not 1 <= self.estimate_thin <= 20:
            raise PlanningError(f"estimate_thin {self.estimate_thin!r} must be in 1..20 (1: every candidate in full)")
        bad_floor = {k: v for k, v in self.min_bound_pct.items() if k not in SURFACES or not 0 <= v <= 100}
        if bad_floor:
            raise PlanningError(f"min_bound_pct {bad_floor} must map surfaces {list(SURFACES)} to 0..100 %")
        if not self.cycle_budget_s >= 0:
            raise PlanningError(f"cycle_budget_s {self.cycle_budget_s!r} must be ≥ 0 (0: no budget)")
        if self.workers < 0:
            raise PlanningError(f"workers {self.workers!r} must be ≥ 0 (0: one per core, 1: in process)")
        if self.chains not in ("all", "needed"):
            raise PlanningError(f"chains {self.chains!r} must be 'all' or 'needed'")
        bad = [s for s in self.surfaces if s not in SURFACES]
        if bad or not self.surfaces:
            raise PlanningError(f"surfaces {list(self.surfaces)} must be some of {list(SURFACES)}")


@dataclass(frozen=True, eq=False)
class StationPlan:
    """One station of the tour: where the base parks, how the bin is identified, what is scanned.

    Attributes:
        rank: visiting order (0 first).
        candidate: the candidate station it is (index around the bin).
        angle_deg: approach direction, bin frame.
        T_bin_base: (4, 4) base pose in the bin frame.
        identify_T_bin_cam: camera pose that sees the board (identification), or None.
        identify_q: its joints, or None.
        identify_reason: why there is no identification pose (board not visible from here:
            the bin pose is carried over from the previous station by the base's move).
        plans: per surface, the station's plan (an ordinary single-station plan).
        motion_s: per surface, modelled motion seconds of the tour (start → last viewpoint).
        cycle_s: modelled seconds spent at this station (identification, both tours, return home).
    """

    rank: int
    candidate: int
    angle_deg: float
    T_bin_base: NDArray[np.float64]
    identify_T_bin_cam: NDArray[np.float64] | None
    identify_q: NDArray[np.float64] | None
    identify_reason: str | None
    plans: dict[str, Plan]
    motion_s: dict[str, float]
    cycle_s: float

    def to_json(self) -> dict[str, Any]:
        return {
            "rank": self.rank,
            "candidate": self.candidate,
            "angle_deg": self.angle_deg,
            "T_bin_base": self.T_bin_base.tolist(),
            "identify": None
            if self.identify_q is None or self.identify_T_bin_cam is None
            else {"T_bin_cam": self.identify_T_bin_cam.tolist(), "q": self.identify_q.tolist()},
            "identify_reason": self.identify_reason,
            "plans": {s: p.plan_id for s, p in self.plans.items()},
            "viewpoints": {s: len(p.viewpoints) for s, p in self.plans.items()},
            "motion_s": self.motion_s,
            "cycle_s": self.cycle_s,
        }


@dataclass(frozen=True)
class SurfaceSummary:
    """Coverage of one surface by the whole plan.

    Attributes:
        area_m2: the surface's area.
        bound_m2: the upper bound: area properly visible from any filtered camera pose (no arm).
        seen_m2: area the selected viewpoints (all stations) properly see.
        viewpoints: selected viewpoints, all stations.
        reachable_m2: the **arm-aware bound**: area properly seen by some reachable, collision-free,
            parking-robust camera pose joined to home, from any evaluated candidate station (every
            candidate unless ``estimate_thin`` > 1). ``seen_m2 ≤ reachable_m2 ≤ bound_m2``: below
            the bound, "no arm at these stations could" (bound − reachable) and "the planner did
            not" (reachable − seen).
        reason: why the surface is not planned (e.g. the mesh has none of its faces).
    """

    area_m2: float
    bound_m2: float
    seen_m2: float
    viewpoints: int
    reachable_m2: float = 0.0
    reason: str | None = None

    @property
    def area_fraction(self) -> float:
        return self.seen_m2 / self.area_m2 if self.area_m2 > 0 else 0.0

    @property
    def bound_fraction(self) -> float:
        return self.seen_m2 / self.bound_m2 if self.bound_m2 > 0 else 0.0

    @property
    def arm_bound_fraction(self) -> float:
        """Seen area over the arm-aware bound (:attr:`reachable_m2`)."""
        return self.seen_m2 / self.reachable_m2 if self.reachable_m2 > 0 else 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "area_fraction": self.area_fraction,
            "bound_fraction": self.bound_fraction,
            "arm_bound_fraction": self.arm_bound_fraction,
            "viewpoints": self.viewpoints,
            "area_m2": self.area_m2,
            "bound_m2": self.bound_m2,
            "seen_m2": self.seen_m2,
            "reachable_m2": self.reachable_m2,
            "reason": self.reason,
        }


@dataclass(frozen=True, eq=False)
class WholePlan:
    """The whole-bin plan: ordered stations, per-surface coverage, the exact bound, modelled cycle time."""

    plan_id: str
    created: str
    bin_type: str
    mesh_sha256: str
    robot_model_id: str
    params: WholeParams
    stations: tuple[StationPlan, ...]
    candidates: tuple[Candidate, ...]
    surfaces: dict[str, SurfaceSummary]
    counts: dict[str, int]
    exact: StationCover | None
    station_scores: dict[str, float]
    base_moves_s: float
    cycle_time_s: float
    times_s: dict[str, float]
    reason: str | None = None

    @property
    def is_empty(self) -> bool:
        return not self.stations

    def to_json(self) -> dict[str, Any]:
        """The whole-plan file body / ``cellctl plan --whole --json`` object."""
        t = self.params.timing
        return {
            "format": WHOLE_FORMAT,
            "plan_id": self.plan_id,
            "created": self.created,
            "bin_type": self.bin_type,
            "mesh_sha256": self.mesh_sha256,
            "robot_model_id": self.robot_model_id,
            "seed": self.params.plan.seed,
            "seed_pct": self.params.plan.seed_pct,
            "stations": [s.to_json() for s in self.stations],
            "candidates": [
                {
                    "candidate": c.index,
                    "angle_deg": c.angle_deg,
                    "xy_m": c.ring_xy.tolist(),
                    "ring": c.ring,
                    "reason": c.reason,
                }
                for c in self.candidates
            ],
            "surfaces": {k: v.to_json() for k, v in self.surfaces.items()},
            "dropped_unconnected": self.counts.get("dropped_unconnected", 0),
            "counts": self.counts,
            "exact_cover": None
            if self.exact is None
            else {
                "stations": self.exact.stations,
                "viewpoints": self.exact.viewpoints,
                "proven": self.exact.proven,
                "seconds": self.exact.seconds,
            },
            "station_scores": self.station_scores,
            "timing_model": {
                "settle_s": t.settle_s,
                "capture_s": t.capture_s,
                "speed_fraction": t.speed_fraction,
                "accel_fraction": t.accel_fraction,
            },
            "base_moves_s": self.base_moves_s,
            "cycle_time_s": self.cycle_time_s,
            "times_s": self.times_s,
            "reason": self.reason,
        }


def whole_path(plans_dir: Any, plan: WholePlan) -> Any:
    """``<plans_dir>/<bin_type>/whole/<plan_id>.json``: beside the per-surface station plans."""
    from pathlib import Path

    from cellctl.planning.planfile import _safe

    return Path(plans_dir) / _safe(plan.bin_type) / "whole" / f"{_safe(plan.plan_id)}.json"


def write_whole(plan: WholePlan, plans_dir: Any, path: Any = None) -> Any:
    """Write every station plan into the cache (``<bin>/<surface>/``) and the whole plan's record.

    Station plans are ordinary plans: the cycle's lookup at station k finds station k's plan
    by its base pose (nearest within tolerance) and adjusts it like any cached plan.
    """
    from cellctl.planning.planfile import plan_path, write_document, write_plan

    for st in plan.stations:
        for p in st.plans.values():
            if p.viewpoints:  # an empty station share is skipped by the cycle, not looked up
                write_plan(p, plan_path(plans_dir, p))
    return write_document(plan.to_json(), path if path is not None else whole_path(plans_dir, plan))


def read_whole(path: Any, plans_dir: Any) -> WholePlan:
    """A whole plan from its record and the station plans in the cache (for pictures and readers).

    Raises:
        PlanCacheError: the record or a station plan is damaged, missing or not a whole plan.
    """
    from pathlib import Path

    from cellctl.errors import PlanCacheError
    from cellctl.geometry.transforms import transform_from_xyz_rpy
    from cellctl.planning.planfile import read_document, read_plan

    d = read_document(path)
    if d.get("format") != WHOLE_FORMAT:
        raise PlanCacheError(f"{path} is not a whole-bin plan (format {d.get('format')!r}, expected {WHOLE_FORMAT!r})")
    t = d["timing_model"]
    params = WholeParams(
        plan=PlanParams(seed=int(d["seed"]), seed_pct=float(d["seed_pct"])),
        timing=TimingModel(
            settle_s=t["settle_s"],
            capture_s=t["capture_s"],
            speed_fraction=t["speed_fraction"],
            accel_fraction=t.get("accel_fraction", 1.0),
        ),
    )
    stations = []
    for st in d["stations"]:
        plans = {
            surf: read_plan(Path(plans_dir) / d["bin_type"] / surf / f"{pid}.json")
            for surf, pid in st["plans"].items()
            if st["viewpoints"].get(surf)
        }
        ident = st["identify"]
        stations.append(
            StationPlan(
                rank=st["rank"],
                candidate=st["candidate"],
                angle_deg=st["angle_deg"],
                T_bin_base=np.array(st["T_bin_base"]),
                identify_T_bin_cam=None if ident is None else np.array(ident["T_bin_cam"]),
                identify_q=None if ident is None else np.array(ident["q"]),
                identify_reason=st["identify_reason"],
                plans=plans,
                motion_s=st["motion_s"],
                cycle_s=st["cycle_s"],
            )
        )
    z = float(stations[0].T_bin_base[2, 3]) if stations else 0.0
    cands = tuple(
        Candidate(
            index=c["candidate"],
            angle_deg=c["angle_deg"],
            T_bin_base=transform_from_xyz_rpy([*c["xy_m"], z], [0.0, 0.0, np.radians(c["angle_deg"]) + np.pi]),
            reason=c["reason"],
            ring_xy=np.array(c["xy_m"]),
            ring=int(c.get("ring", 0)),
        )
        for c in d["candidates"]
    )
    surfaces = {
        k: SurfaceSummary(v["area_m2"], v["bound_m2"], v["seen_m2"], v["viewpoints"], v["reachable_m2"], v["reason"])
        for k, v in d["surfaces"].items()
    }
    ex = d["exact_cover"]
    return WholePlan(
        plan_id=d["plan_id"],
        created=d["created"],
        bin_type=d["bin_type"],
        mesh_sha256=d["mesh_sha256"],
        robot_model_id=d["robot_model_id"],
        params=params,
        stations=tuple(stations),
        candidates=cands,
        surfaces=surfaces,
        counts=d["counts"],
        exact=None if ex is None else StationCover(ex["stations"], ex["viewpoints"], ex["proven"], ex["seconds"]),
        station_scores=d["station_scores"],
        base_moves_s=d["base_moves_s"],
        cycle_time_s=d["cycle_time_s"],
        times_s=d["times_s"],
        reason=d["reason"],
    )
