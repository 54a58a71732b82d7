"""The plan: what the offline planner produces, the plan file stores and every reader uses.

A :class:`Plan` holds the ordered viewpoints (:class:`PlannedViewpoint`), every reachable
candidate (:class:`ReachableViewpoint`, for collect cycles and the twin's dataset), the
parameters that made it (:class:`PlanParams`), the base pose (:class:`BasePose`), and what
each stage counted and spent (:class:`CandidateCounts`, :class:`StageCounts`,
:class:`AreaStats`, :class:`StageTimes`, :class:`SAStats`).

JSON layout (``cellctl-plan/1``, unchanged by the typed model): :meth:`Plan.to_json` writes
the keys in the order and with the optional keys the untyped dict had, so a plan read with
:meth:`Plan.from_json` and written again gives the same JSON; :meth:`Plan.from_json` checks
every field of a file (types, shapes, finite numbers, no unknown keys) and raises
:class:`~cellctl.errors.PlanCacheError` naming the first bad one.

Frames in names (``T_bin_cam``: camera pose in the bin frame), metres and radians. Arrays
are read-only: a plan is a record, not a work area. Records holding arrays compare by
identity (``eq=False``: an array has no truth value); compare plans by :meth:`Plan.to_json`.
Light module: numpy only (no OMPL, trimesh or open3d), the supervisor may import it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, cast, get_type_hints

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import CellError, PlanCacheError, PlanningError
from cellctl.geometry.camera import CameraModel
from cellctl.surface import check_surface

__all__ = [
    "AreaStats",
    "BasePose",
    "CandidateCounts",
    "Plan",
    "PlanParams",
    "PlannedViewpoint",
    "ReachableViewpoint",
    "SAStats",
    "StageCounts",
    "StageTimes",
    "frozen_array",
]

_OMIT_NONE = {"omit_none": True}
"""Field metadata: the key is absent from the JSON while the value is None (a stage that did not run)."""


class _Malformed(Exception):
    """A field of a plan's JSON is not what the model expects (``where`` + what is wrong)."""


# --- parameters --------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanParams:
    """Everything that shapes a plan (paper Table 1 defaults). Lengths m, angles rad unless named _deg.

    Attributes:
        surface: "external" or "internal".
        seed_pct: p_SP, % of the surface's faces used as seeds.
        mode: "fast" or "paper".
        seed: RNG seed (seeds, SA, ACO).
        distances: d_0 … d_{D−1} from the seed, preference order.
        max_reach: distance filter radius around the robot base (r̄).
        n_roll: rolls about the optical axis tried by reachability.
        sa_pct: p_SA, % of the Greedy Area set SA removes (0: skip SA).
        sa_iterations: SA steps.
        margin: collision clearance.
        camera: intrinsics and usable ranges.
        paper_budget_s: RRT* time per query in paper mode (the paper's MoveIt used ~1.2 s).
        paper_fallback: paper mode: when RRT* ends its budget without a solution, RRTConnect
            decides feasibility. Our RRT* calls Python collision checks and runs ~20× fewer
            iterations per second than the paper's C++ MoveIt/FCL; alone it rejects about half
            of the goals RRTConnect reaches in 0.03 s, which would compare coverage against a
            handicapped baseline. The RRT* budget (the paper's cost) is still spent in full.
        fallback_budget_s: RRTConnect limit for colliding straight motions in fast mode.
        simplify_s: simplification limit per planned path.
        cover_time_limit_s: HiGHS limit for the exact set-cover bound.
        q_start: the robot's current configuration (tour start); None → the robot's home.
        robust_m, robust_deg: a viewpoint is kept only if it stays reachable (IK next to its
            joints, same arm shape, collision-free) when the base parks this far off in x, y
            and yaw; so a cached plan can be adjusted to the next park instead of replanned.
            0 disables the check.
        opening_views: internal surface: also look at each seed from the top opening's axis
            (:func:`cellctl.planning.viewpoints.opening_viewpoints`), after the fixed distances.
            A plan file holds the key only when it is on: files written before it (without
            such views) read as off.
    """

    surface: str = "external"
    seed_pct: float = 10.0
    mode: str = "fast"
    seed: int = 0
    distances: tuple[float, ...] = (0.3, 0.4)
    max_reach: float = 1.3
    n_roll: int = 12
    sa_pct: float = 15.0
    sa_iterations: int = 4000
    margin: float = 0.005
    camera: CameraModel = field(default_factory=CameraModel)
    paper_budget_s: float = 1.0
    paper_fallback: bool = True
    fallback_budget_s: float = 0.2
    simplify_s: float = 0.05
    cover_time_limit_s: float = 5.0
    q_start: tuple[float, ...] | None = None
    robust_m: float = 0.04
    robust_deg: float = 2.0
    opening_views: bool = True

    def check(self) -> None:
        """Raise PlanningError naming the first bad parameter."""
        check_surface(self.surface, PlanningError)
        if self.mode not in ("fast", "paper"):
            raise PlanningError(f"mode {self.mode!r} is unknown; expected 'fast' or 'paper'")
        if not 0 < self.seed_pct <= 100:
            raise PlanningError(f"seed_pct {self.seed_pct!r} must be in (0, 100]")
        if not 0 <= self.sa_pct < 100:
            raise PlanningError(f"sa_pct {self.sa_pct!r} must be in [0, 100)")
        if not self.distances or any(d <= 0 for d in self.distances):
            raise PlanningError(f"distances {list(self.distances)} must be positive metres")
        if self.n_roll < 1:
            raise PlanningError(f"n_roll {self.n_roll!r} must be >= 1")
        if self.q_start is not None and len(self.q_start) != 6:
            raise PlanningError(f"q_start must have 6 joint angles, got {len(self.q_start)}")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["distances"] = list(self.distances)
        d["camera"] = self.camera.to_json()
        d["q_start"] = list(self.q_start) if self.q_start is not None else None
        if not self.opening_views:
            del d["opening_views"]  # absent = off: how every file written before the option reads
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PlanParams:
        """Parameters as a plan file records them; keys added since a file was written take their defaults.

        Raises:
            PlanCacheError: not an object, an unknown key, or a bad camera.
        """
        try:
            return cls._from_json(d)
        except _Malformed as err:
            raise PlanCacheError(f"plan parameters are malformed: {err}") from None

    @classmethod
    def _from_json(cls, d: Any) -> PlanParams:
        d = dict(_object(d, "params", cls))
        cam = d.pop("camera", {})
        if not isinstance(cam, dict):
            raise _Malformed(f"params.camera is {type(cam).__name__}, expected an object")
        if "distances" in d:
            d["distances"] = tuple(_seq(d["distances"], "params.distances"))
        if d.get("q_start") is not None:
            d["q_start"] = tuple(_seq(d["q_start"], "params.q_start"))
        d.setdefault("opening_views", False)  # a file without the key was planned without them
        defaults = cls()
        for k, v in d.items():
            _check_param(k, v, getattr(defaults, k))
        try:
            return cls(camera=CameraModel(**cam), **d)
        except (TypeError, CellError) as err:
            raise _Malformed(f"params.camera: {err}") from None


def _check_param(name: str, v: Any, default: Any) -> None:
    """A parameter's JSON value has the type of its default (numbers stay numbers, flags flags)."""
    where = f"params.{name}"
    if isinstance(default, bool):
        ok = isinstance(v, bool)
    elif isinstance(default, int | float):
        ok = _is_number(v)
    elif isinstance(default, str):
        ok = isinstance(v, str)
    else:  # tuples (distances, q_start) and None (q_start)
        ok = v is None or (isinstance(v, tuple) and all(_is_number(x) for x in v))
    if not ok:
        raise _Malformed(f"{where} is {v!r:.40}, expected a value like {default!r}")


def _seq(v: Any, where: str) -> list[Any]:
    if not isinstance(v, list):
        raise _Malformed(f"{where} is {type(v).__name__}, expected a list")
    return v


# --- validation helpers --------------------------------------------------------------------


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _number(v: Any, where: str) -> float:
    if not _is_number(v):
        raise _Malformed(f"{where} is {v!r:.30}, expected a finite number")
    return cast(float, v)  # int or float, kept as written: the JSON stays the same


def _integer(v: Any, where: str) -> int:
    if not isinstance(v, int) or isinstance(v, bool):
        raise _Malformed(f"{where} is {v!r:.30}, expected an integer")
    return v


def _text(v: Any, where: str, allow_empty: bool = False) -> str:
    if not isinstance(v, str) or (not v and not allow_empty):
        raise _Malformed(f"{where} is {v!r:.60}, expected a non-empty string")
    return v


def _array(v: Any, where: str, shape: tuple[int, ...], what: str) -> NDArray[np.float64]:
    """A read-only float64 array of ``shape`` (-1: any length) from nested lists of finite numbers."""
    ok = isinstance(v, list)
    if ok:
        try:
            a = np.array(v, dtype=np.float64)
        except (ValueError, TypeError):
            ok = False
    if ok and len(shape) == 2 and shape[0] == -1 and a.size == 0:
        a = a.reshape(0, shape[1])  # an empty path is [] in JSON
    ok = (
        ok
        and a.ndim == len(shape)
        and all(s in (-1, n) for s, n in zip(shape, a.shape, strict=True))
        and bool(np.isfinite(a).all())
        and _only_numbers(v)
    )
    if not ok:
        raise _Malformed(f"{where} is not {what}")
    a.setflags(write=False)
    return a


def _only_numbers(v: Any) -> bool:
    if isinstance(v, list):
        return all(_only_numbers(x) for x in v)
    return _is_number(v)


def _face_ids(v: Any, where: str) -> NDArray[np.int64]:
    if not isinstance(v, list) or not all(isinstance(f, int) and not isinstance(f, bool) for f in v):
        raise _Malformed(f"{where} is not a list of face ids")
    return frozen_array(v, np.int64)


def frozen_array(a: Any, dtype: type = np.float64) -> NDArray[Any]:
    """A read-only copy of ``a`` (the arrays a plan holds)."""
    out = np.array(a, dtype=dtype)
    out.setflags(write=False)
    return out


def _object(v: Any, where: str, cls: type) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise _Malformed(f"{where} is {type(v).__name__}, expected an object")
    names = [f.name for f in fields(cls)]
    unknown = sorted(set(v) - set(names))
    if unknown:
        raise _Malformed(f"{where} has unknown keys {unknown}; expected some of {names}")
    return v


def _flat_record(cls: type, v: Any, where: str) -> Any:
    """A record of numbers (``int``, ``float``, optionally ``| None``) from a JSON object."""
    d = _object(v, where, cls)
    hints = get_type_hints(cls)
    kw: dict[str, Any] = {}
    for f in fields(cls):
        hint = str(hints[f.name])
        if f.name not in d:
            if "None" not in hint:  # only the optional keys may be absent
                raise _Malformed(f"{where}.{f.name} is missing")
            continue
        x = d[f.name]
        if x is None and "None" in hint:
            kw[f.name] = None
        elif "int" in hint and "float" not in hint:
            kw[f.name] = _integer(x, f"{where}.{f.name}")
        else:
            kw[f.name] = _number(x, f"{where}.{f.name}")
    return cls(**kw)


def _dump(rec: Any) -> dict[str, Any]:
    """A flat record as JSON, in field order, without the unset optional keys."""
    return {
        f.name: getattr(rec, f.name)
        for f in fields(rec)
        if not (getattr(rec, f.name) is None and f.metadata.get("omit_none"))
    }


# --- sub-records -------------------------------------------------------------------------


@dataclass(frozen=True)
class CandidateCounts:
    """Viewpoint candidates left after each step (paper Table 2's columns)."""

    generated: int = 0
    filtered: int = 0
    reachable: int = 0
    greedy: int = 0
    annealed: int = 0
    optimal_cover: int | None = None
    """Size of the exact minimum set cover (HiGHS), None when it was not computed."""


@dataclass(frozen=True)
class StageCounts:
    """What each stage counted; None (absent from the JSON) for a stage that did not run or a mode without it."""

    seeds: int | None = field(default=None, metadata=_OMIT_NONE)
    after_height: int | None = field(default=None, metadata=_OMIT_NONE)
    after_distance: int | None = field(default=None, metadata=_OMIT_NONE)
    after_occlusion: int | None = field(default=None, metadata=_OMIT_NONE)
    after_camera_collision: int | None = field(default=None, metadata=_OMIT_NONE)
    reach_tried: int | None = field(default=None, metadata=_OMIT_NONE)
    reach_checks: int | None = field(default=None, metadata=_OMIT_NONE)
    reach_planner_queries: int | None = field(default=None, metadata=_OMIT_NONE)
    reach_rrtconnect_fallbacks: int | None = field(default=None, metadata=_OMIT_NONE)
    matrix_pairs: int | None = field(default=None, metadata=_OMIT_NONE)
    matrix_straight: int | None = field(default=None, metadata=_OMIT_NONE)  # fast mode
    matrix_planned: int | None = field(default=None, metadata=_OMIT_NONE)
    matrix_failed: int | None = field(default=None, metadata=_OMIT_NONE)
    matrix_rrtconnect_fallbacks: int | None = field(default=None, metadata=_OMIT_NONE)  # paper mode
    tour_failed_edges: int | None = field(default=None, metadata=_OMIT_NONE)  # fast mode
    dropped_unconnected: int | None = field(default=None, metadata=_OMIT_NONE)
    optimal_cover_proven: int | None = field(default=None, metadata=_OMIT_NONE)


@dataclass(frozen=True)
class AreaStats:
    """Areas of the planned surface, m², and the selection's loss against all reachable viewpoints, %."""

    mesh_m2: float
    visible_all_m2: float = 0.0
    visible_selected_m2: float = 0.0
    loss_pct: float = 0.0
    greedy_loss_pct: float | None = field(default=None, metadata=_OMIT_NONE)


@dataclass(frozen=True)
class StageTimes:
    """Seconds per stage (the ``times_s`` keys of :mod:`cellctl.planning.pipeline`'s table)."""

    generate_filter: float = 0.0
    reachability: float = 0.0
    visibility: float = 0.0
    selection: float = 0.0
    distance_matrix: float = 0.0
    ordering: float = 0.0
    exact_cover_s: float | None = field(default=None, metadata=_OMIT_NONE)
    total: float = 0.0


@dataclass(frozen=True)
class SAStats:
    """Simulated annealing: steps run and moves accepted."""

    iterations: int
    accepted: int


@dataclass(frozen=True, eq=False)
class BasePose:
    """Where the robot base stood for the plan (bin frame), and its inverse.

    Attributes:
        T_bin_base: (4, 4) robot base pose in the bin frame.
        T_base_bin: (4, 4) bin pose in the robot base frame (the lookup compares it with the measured one).
    """

    T_bin_base: NDArray[np.float64]
    T_base_bin: NDArray[np.float64]


# --- viewpoints ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ReachableViewpoint:
    """A viewpoint the robot reaches from the plan's base pose (selected or not).

    Attributes:
        T_bin_cam: (4, 4) camera optical pose, bin frame.
        q: (6,) joint angles reaching it, rad.
        faces: (k,) ids of the surface faces it properly sees.
        seed_face: the face whose seed generated it.
    """

    T_bin_cam: NDArray[np.float64]
    q: NDArray[np.float64]
    faces: NDArray[np.int64]
    seed_face: int

    def to_json(self) -> dict[str, Any]:
        return {
            "T_bin_cam": self.T_bin_cam.tolist(),
            "q": self.q.tolist(),
            "faces": self.faces.tolist(),
            "seed_face": self.seed_face,
        }

    @classmethod
    def _from_json(cls, v: Any, where: str) -> ReachableViewpoint:
        d = _viewpoint_object(v, where, cls)
        return cls(
            T_bin_cam=_array(d.get("T_bin_cam"), f"{where}.T_bin_cam", (4, 4), "a 4x4 matrix of finite numbers"),
            q=_array(d.get("q"), f"{where}.q", (6,), "6 finite joint angles"),
            faces=_face_ids(d.get("faces"), f"{where}.faces"),
            seed_face=_integer(d.get("seed_face"), f"{where}.seed_face"),
        )


@dataclass(frozen=True, eq=False)
class PlannedViewpoint:
    """One viewpoint of the tour, in visiting order.

    The wire form the lookup sends (re-expressed at the measured bin pose) is
    :class:`cellctl.messages.PlannedViewpoint`.

    Attributes:
        index: rank in the tour (0 = first visited).
        candidate: its column among the plan's reachable candidates at selection time.
        T_bin_cam: (4, 4) camera optical pose, bin frame.
        T_base_cam: (4, 4) the same pose in the robot base frame (at the plan's base pose).
        q: (6,) joint angles, rad.
        roll: rotation about the optical axis reachability chose, rad.
        faces: (k,) ids of the surface faces it properly sees.
        seed_face: the face whose seed generated it.
        approach: (K, 6) planned joint waypoints from the previous viewpoint (ends excluded);
            (0, 6) when the straight joint motion is free.
        cost_from_prev: path cost of the move from the previous viewpoint (or the start).
    """

    index: int
    candidate: int
    T_bin_cam: NDArray[np.float64]
    T_base_cam: NDArray[np.float64]
    q: NDArray[np.float64]
    roll: float
    faces: NDArray[np.int64]
    seed_face: int
    approach: NDArray[np.float64]
    cost_from_prev: float

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "candidate": self.candidate,
            "T_bin_cam": self.T_bin_cam.tolist(),
            "T_base_cam": self.T_base_cam.tolist(),
            "q": self.q.tolist(),
            "roll": self.roll,
            "faces": self.faces.tolist(),
            "seed_face": self.seed_face,
            "approach": self.approach.tolist(),
            "cost_from_prev": self.cost_from_prev,
        }

    @classmethod
    def _from_json(cls, v: Any, where: str) -> PlannedViewpoint:
        d = _viewpoint_object(v, where, cls)
        return cls(
            index=_integer(d.get("index"), f"{where}.index"),
            candidate=_integer(d.get("candidate"), f"{where}.candidate"),
            T_bin_cam=_array(d.get("T_bin_cam"), f"{where}.T_bin_cam", (4, 4), "a 4x4 matrix of finite numbers"),
            T_base_cam=_array(d.get("T_base_cam"), f"{where}.T_base_cam", (4, 4), "a 4x4 matrix of finite numbers"),
            q=_array(d.get("q"), f"{where}.q", (6,), "6 finite joint angles"),
            roll=_number(d.get("roll"), f"{where}.roll"),
            faces=_face_ids(d.get("faces"), f"{where}.faces"),
            seed_face=_integer(d.get("seed_face"), f"{where}.seed_face"),
            approach=_array(d.get("approach"), f"{where}.approach", (-1, 6), "a list of 6-joint waypoints"),
            cost_from_prev=_number(d.get("cost_from_prev"), f"{where}.cost_from_prev"),
        )


def _viewpoint_object(v: Any, where: str, cls: type) -> dict[str, Any]:
    d = _object(v, where, cls)
    # the keys every reader needs first, so a foreign viewpoint names the one that matters
    missing = [f.name for f in fields(cls) if f.name not in d]
    if missing:
        raise _Malformed(f"{where} lacks {missing}")
    return d


def _viewpoints(v: Any, where: str, cls: Any) -> tuple[Any, ...]:
    if not isinstance(v, list):
        raise _Malformed(f"{where} is {type(v).__name__}, expected a list")
    return tuple(cls._from_json(x, f"{where}[{k}]") for k, x in enumerate(v))


# --- the plan ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Plan:
    """An ordered, reachable set of viewpoints for one bin type, surface and base pose.

    Attributes:
        plan_id: 12 hex digits, the file name in the cache.
        created: UTC time, ISO 8601 (``2026-12-01T18:00:00Z``); the lookup prefers newer plans.
        bin_type: catalog name (or the mesh file's name).
        mesh_sha256: hash of the mesh the plan was made on (a changed mesh is a cache miss).
        robot_model_id: kinematic model id (a changed robot is a cache miss).
        surface: "external" or "internal".
        mode: "fast" or "paper".
        params: what shaped it.
        base: robot base pose in the bin frame and its inverse.
        q_start: (6,) the tour's start configuration, rad.
        counts: candidates after each step.
        stage_counts: what each stage counted.
        area: areas seen, m², and the selection's loss.
        times_s: seconds per stage.
        tour_cost: path cost of the whole tour.
        coverage: fraction of the surface's area the tour sees.
        viewpoints: the tour, in visiting order.
        reachable: every reachable, connected candidate (collect cycles visit all of them).
        reason: why the plan is empty; None for a plan with viewpoints.
        mesh_faces: faces of the whole mesh (face ids index this mesh).
        surface_faces: faces of the planned surface.
        sa: simulated annealing statistics; None for an empty plan.
        job_id: the planner worker's job that made it; None for ``cellctl plan``.
    """

    plan_id: str
    created: str
    bin_type: str
    mesh_sha256: str
    robot_model_id: str
    surface: str
    mode: str
    params: PlanParams
    base: BasePose
    q_start: NDArray[np.float64]
    counts: CandidateCounts
    stage_counts: StageCounts
    area: AreaStats
    times_s: StageTimes
    tour_cost: float
    coverage: float
    viewpoints: tuple[PlannedViewpoint, ...]
    reachable: tuple[ReachableViewpoint, ...]
    reason: str | None
    mesh_faces: int
    surface_faces: int
    sa: SAStats | None = None
    job_id: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The plan file's ``plan`` object (keys in the order ``cellctl-plan/1`` files have them)."""
        d: dict[str, Any] = {
            "plan_id": self.plan_id,
            "created": self.created,
            "bin_type": self.bin_type,
            "mesh_sha256": self.mesh_sha256,
            "robot_model_id": self.robot_model_id,
            "surface": self.surface,
            "mode": self.mode,
            "params": self.params.to_json(),
            "T_bin_base": self.base.T_bin_base.tolist(),
            "T_base_bin": self.base.T_base_bin.tolist(),
            "q_start": self.q_start.tolist(),
            "counts": _dump(self.counts),
            "stage_counts": _dump(self.stage_counts),
            "area": _dump(self.area),
            "times_s": _dump(self.times_s),
            "tour_cost": self.tour_cost,
            "coverage": self.coverage,
            "viewpoints": [v.to_json() for v in self.viewpoints],
            "reachable": [v.to_json() for v in self.reachable],
            "reason": self.reason,
            "mesh_faces": self.mesh_faces,
            "surface_faces": self.surface_faces,
        }
        if self.sa is not None:
            d["sa"] = _dump(self.sa)
        if self.job_id is not None:
            d["job_id"] = self.job_id
        return d

    @classmethod
    def from_json(cls, d: Any) -> Plan:
        """Check and type a plan file's ``plan`` object.

        Raises:
            PlanCacheError: ``plan <id> is malformed: <field> …`` for the first field that is
                missing, of the wrong type or shape, not finite, or not one of the plan's keys.
        """
        pid = d.get("plan_id") if isinstance(d, dict) else None
        try:
            return cls._from_json(d)
        except _Malformed as err:
            raise PlanCacheError(f"plan {pid!r:.40} is malformed: {err}") from None

    @classmethod
    def _from_json(cls, d: Any) -> Plan:
        if not isinstance(d, dict):
            raise _Malformed(f"the plan is {type(d).__name__}, expected an object")
        keys = ["T_bin_base", "T_base_bin"] + [f.name for f in fields(cls) if f.name != "base"]
        unknown = sorted(set(d) - set(keys))
        if unknown:
            raise _Malformed(f"unknown keys {unknown}; a plan has {keys}")
        for k in ("plan_id", "mesh_sha256", "robot_model_id"):
            _text(d.get(k), k)
        reason = d.get("reason")
        if reason is not None:
            _text(reason, "reason")
        job_id = d.get("job_id")
        if job_id is not None:
            _text(job_id, "job_id")
        matrix = "a 4x4 matrix of finite numbers"
        T_base_bin = _array(d.get("T_base_bin"), "T_base_bin", (4, 4), matrix)
        T_bin_base = _array(d.get("T_bin_base"), "T_bin_base", (4, 4), matrix)
        if not np.allclose(T_bin_base @ T_base_bin, np.eye(4), atol=1e-6):
            raise _Malformed("T_bin_base and T_base_bin are not each other's inverse")
        sa = d.get("sa")
        return cls(
            plan_id=d["plan_id"],
            created=_text(d.get("created"), "created", allow_empty=True),
            bin_type=_text(d.get("bin_type"), "bin_type"),
            mesh_sha256=d["mesh_sha256"],
            robot_model_id=d["robot_model_id"],
            surface=_text(d.get("surface"), "surface"),
            mode=_text(d.get("mode"), "mode"),
            params=PlanParams._from_json(d.get("params")),
            base=BasePose(T_bin_base=T_bin_base, T_base_bin=T_base_bin),
            q_start=_array(d.get("q_start"), "q_start", (6,), "6 finite joint angles"),
            counts=_flat_record(CandidateCounts, d.get("counts"), "counts"),
            stage_counts=_flat_record(StageCounts, d.get("stage_counts"), "stage_counts"),
            area=_flat_record(AreaStats, d.get("area"), "area"),
            times_s=_flat_record(StageTimes, d.get("times_s"), "times_s"),
            tour_cost=_number(d.get("tour_cost"), "tour_cost"),
            coverage=_number(d.get("coverage"), "coverage"),
            viewpoints=_viewpoints(d.get("viewpoints"), "viewpoints", PlannedViewpoint),
            reachable=_viewpoints(d.get("reachable"), "reachable", ReachableViewpoint),
            reason=reason,
            mesh_faces=_integer(d.get("mesh_faces"), "mesh_faces"),
            surface_faces=_integer(d.get("surface_faces"), "surface_faces"),
            sa=None if sa is None else _flat_record(SAStats, sa, "sa"),
            job_id=job_id,
        )

    @property
    def is_empty(self) -> bool:
        """No viewpoint: :attr:`reason` says why."""
        return not self.viewpoints
