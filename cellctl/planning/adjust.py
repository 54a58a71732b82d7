"""Cache lookup with pose tolerance: reuse a plan at a slightly different bin pose (paper §IV-B).

Within tolerance, every viewpoint is re-expressed at the measured bin pose (the plan stores
it in the bin frame), IK is re-solved next to the planned joints, and the new configurations
and the straight motions between consecutive ones are collision-checked. A viewpoint out of
reach or in collision, a pose beyond tolerance, a changed mesh or a changed robot model is a
miss with the reason; a straight move that now grazes the bin is only noted (the robot plans
that move around the bin online).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.geometry.transforms import invert, pose_error
from cellctl.planning.plan import Plan, PlannedViewpoint, ReachableViewpoint
from cellctl.planning.planfile import list_plans
from cellctl.planning.robot import RobotModel

__all__ = ["NEARBY_VIEWS", "AdjustedViewpoint", "LookupResult", "adjust_plan", "lookup_plan", "nearby_views"]


@dataclass(frozen=True)
class AdjustedViewpoint:
    """A plan's viewpoint re-expressed at the measured bin pose (what the robot is sent to).

    Attributes:
        index: visiting rank.
        T_base_cam: (4, 4) camera optical pose in the robot base frame at the measured bin pose.
        q: (6,) joint angles re-solved next to the planned ones, rad.
        faces: ids of the surface faces it sees.
    """

    index: int
    T_base_cam: NDArray[np.float64]
    q: NDArray[np.float64]
    faces: tuple[int, ...]


@dataclass
class LookupResult:
    """Outcome of a cache lookup.

    Attributes:
        hit: a usable (possibly adjusted) plan was found.
        reason: why not (or a note on the hit).
        plan_id: the plan looked at.
        viewpoints: visiting order, at the measured bin pose.
        coverage: fraction of the surface's area the plan sees.
        adjusted: the viewpoints were re-expressed at a different bin pose.
        translation_mm, rotation_deg: measured-vs-planned bin pose difference.
    """

    hit: bool
    reason: str
    plan_id: str | None = None
    viewpoints: list[AdjustedViewpoint] = field(default_factory=list)
    coverage: float = 0.0
    adjusted: bool = False
    translation_mm: float | None = None
    rotation_deg: float | None = None


def adjust_plan(
    plan: Plan,
    T_base_bin: NDArray[np.float64],
    mesh: BinMesh,
    robot: RobotModel,
    use_all: bool = False,
) -> tuple[list[AdjustedViewpoint] | None, str]:
    """Re-express a plan's viewpoints at ``T_base_bin``; None + reason if any fails.

    Args:
        use_all: take every reachable viewpoint (data collection) instead of the tour.
    """
    from cellctl.planning.collision import PlanningWorld
    from cellctl.planning.reach import wrap_towards

    world = PlanningWorld(mesh, robot, invert(T_base_bin), margin=float(plan.params.margin))
    src: list[PlannedViewpoint] | list[ReachableViewpoint] = list(plan.viewpoints)
    if use_all:
        # every reachable viewpoint, visited nearest-neighbour in joint space from the start
        left = list(plan.reachable)
        q = plan.q_start
        ordered: list[ReachableViewpoint] = []
        while left:
            k = int(np.argmin([np.linalg.norm(v.q - q) for v in left]))
            ordered.append(left.pop(k))
            q = ordered[-1].q
        src = ordered
    out: list[AdjustedViewpoint] = []
    Q = []
    for k, vp in enumerate(src):
        T = np.asarray(T_base_bin) @ vp.T_bin_cam
        q_plan = vp.q
        S = robot.ik_cam(T)
        if len(S) == 0:
            return None, f"viewpoint {k} is out of reach at the measured bin pose"
        S = wrap_towards(S, q_plan, robot)
        q = S[np.argmin(np.linalg.norm(S - q_plan, axis=1))]
        if np.abs(q - q_plan).max() > 0.5:
            return None, (
                f"viewpoint {k}: nearest IK solution moves a joint by {np.abs(q - q_plan).max():.2f} rad "
                "(> 0.5 rad): the arm would change configuration"
            )
        Q.append(q)
        out.append(AdjustedViewpoint(index=k, T_base_cam=T, q=q, faces=tuple(int(f) for f in vp.faces)))
    if not Q:
        return out, "empty plan"
    Qa = np.array(Q)
    free = world.robot_free(Qa)
    if not free.all():
        k = int(np.flatnonzero(~free)[0])
        return None, f"viewpoint {k} collides at the measured bin pose ({', '.join(world.sim.explain(Qa[k]))})"
    if not use_all:
        # consecutive moves the plan made as straight joint motions must stay free
        straight = [k for k, vp in enumerate(plan.viewpoints) if len(vp.approach) == 0]
        pairs = [(k - 1, k) for k in straight if k > 0]
        if pairs:
            A = Qa[[a for a, _ in pairs]]
            B = Qa[[b for _, b in pairs]]
            ok = world.motion_free(A, B)
            if not ok.all():
                # The configurations are free; only the joint-space line between two of them
                # grazes the moved bin. The robot plans such a move around the bin online
                # (straight line first, else RRTConnect), so this costs time, not coverage.
                a, b = pairs[int(np.flatnonzero(~ok)[0])]
                return out, f"ok; {int((~ok).sum())} straight move(s) (first {a}→{b}) now need a planned path"
    return out, "ok"


NEARBY_VIEWS: tuple[tuple[float, float], ...] = (
    (0.010, 0.0),
    (0.020, 0.0),
    (0.0, 15.0),
    (0.0, -15.0),
    (0.015, 30.0),
    (0.015, -30.0),
)
"""(standoff back along the optical axis m, roll about it deg) of :func:`nearby_views`, nearest first."""


def nearby_views(T_cam: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """Camera poses that keep a viewpoint's view when its own pose is refused at run time.

    A tolerated parking or pose-measurement error moves the bin by millimetres against a plan
    whose configurations keep a 5 mm margin: an internal viewpoint whose wrist passes the rim
    closely can touch it (demo, dirty cycle: wrist_3 vs bin, every IK solution). Backing the
    camera off along its optical axis (the same spot, a 1-3 % larger footprint at ~0.5 m) pulls
    the wrist out of the cavity; rolling it about the axis (the same footprint, turned) swings
    the wrist and camera body around the rim. ``T_cam`` in any frame, optical +Z forward.
    """
    T = np.asarray(T_cam, dtype=np.float64)
    out = []
    for back, roll in NEARBY_VIEWS:
        a = np.deg2rad(roll)
        Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        N = np.eye(4)
        N[:3, :3] = T[:3, :3] @ Rz
        N[:3, 3] = T[:3, 3] - back * T[:3, 2]
        out.append(N)
    return out


def lookup_plan(
    plans_dir: Path | str,
    bin_type: str,
    surface: str,
    T_base_bin: NDArray[np.float64],
    mesh: BinMesh,
    robot: RobotModel,
    tolerance_mm: float,
    tolerance_deg: float,
    use_all: bool = False,
) -> LookupResult:
    """Find a cached plan for this bin at this pose and adjust it; miss with the reason otherwise."""
    plans, skipped = list_plans(plans_dir, bin_type, surface)
    note = f" ({len(skipped)} damaged plan file(s) skipped: {skipped[0]})" if skipped else ""
    if not plans:
        return LookupResult(False, f"no plan for bin type {bin_type!r}, {surface} surface{note}")
    rid = robot.model_id()
    good = [p for p in plans if p.mesh_sha256 == mesh.sha256 and p.robot_model_id == rid]
    if not good:
        p = plans[0]
        what = "mesh hash" if p.mesh_sha256 != mesh.sha256 else "robot model"
        return LookupResult(False, f"plan {p.plan_id} was made for another {what}; replan{note}", p.plan_id)
    good = [p for p in good if p.viewpoints] or good

    def err(p: Plan) -> tuple[float, float]:
        dt, dr = pose_error(p.base.T_base_bin, T_base_bin)
        return dt * 1000.0, float(np.degrees(dr))

    best = min(good, key=lambda p: err(p)[0] / tolerance_mm + err(p)[1] / tolerance_deg)
    dmm, ddeg = err(best)
    res = LookupResult(False, "", best.plan_id, translation_mm=dmm, rotation_deg=ddeg)
    if not best.viewpoints:
        res.reason = f"plan {best.plan_id} is empty: {best.reason}"
        return res
    if dmm > tolerance_mm or ddeg > tolerance_deg:
        res.reason = (
            f"bin pose differs from plan {best.plan_id} by {dmm:.1f} mm / {ddeg:.2f} deg; "
            f"tolerance is {tolerance_mm:g} mm / {tolerance_deg:g} deg"
        )
        return res
    vps, why = adjust_plan(best, T_base_bin, mesh, robot, use_all)
    if vps is None:
        res.reason = f"plan {best.plan_id} cannot be adjusted: {why}"
        return res
    res.hit = True
    res.viewpoints = vps
    res.coverage = float(best.coverage)
    res.adjusted = dmm > 1e-3 or ddeg > 1e-4
    res.reason = "within tolerance" + ("" if why == "ok" else why[2:]) + note
    return res
