"""The planner worker's ``wash_plan`` op: a :class:`~cellctl.messages.WashPlanRequest` → the plan
as a :class:`~cellctl.messages.WashPlanReply` (sweeps with their joints and spot paths, the
faces they cover, the unwashable pieces with why). Runs in the worker: the wash planner pulls
the planning stack (IK, distance grids, ray casts) the supervisor must not import.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.config import CellConfig
from cellctl.errors import PlanningError
from cellctl.messages import PlannedSweep, UnwashablePiece, WashPlanReply, WashPlanRequest

__all__ = ["MeshCache", "wash_plan_reply"]


class MeshCache:
    """Bin meshes by type, loaded once per worker."""

    def __init__(self, cfg: CellConfig) -> None:
        self.cfg = cfg
        self._meshes: dict[str, Any] = {}
        self._catalog: Any = None

    def get(self, bin_type: str) -> Any:  # BinMesh
        from cellctl.geometry.catalog import load_catalog

        if self._catalog is None:
            self._catalog = load_catalog(self.cfg.path(self.cfg.catalog), self.cfg.root)
        if bin_type not in self._meshes:
            self._meshes[bin_type] = self._catalog.load_mesh(bin_type)  # ConfigError for an unknown type
        return self._meshes[bin_type]


def _ids(mask: np.ndarray) -> list[int]:
    return np.flatnonzero(mask).tolist()


def wash_plan_reply(cfg: CellConfig, meshes: MeshCache, req: WashPlanRequest) -> WashPlanReply:
    """Plan the wash ``req`` asks for.

    Raises:
        ConfigError: unknown bin type. PlanningError / ClassifierError: a station not in the bin
        frame, a malformed dirt map.
    """
    from cellctl.planning.raycast import RayCaster
    from cellctl.planning.robot import default_robot_model
    from cellctl.washing.nozzle import NozzleModel
    from cellctl.washing.plan import WashParams, plan_wash
    from cellctl.washing.spots import spray_path

    for k, st in enumerate(req.stations):
        if st.frame_id != "bin":
            raise PlanningError(f"wash plan station {k} has frame_id {st.frame_id!r}; expected 'bin' (T_bin_base)")
    mesh = meshes.get(req.bin_type)
    nozzle = NozzleModel.from_config(cfg.nozzle)
    params = WashParams(threshold=req.threshold, margin_m=req.margin_m, seed=req.seed, q_start=tuple(req.q_start))
    plan = plan_wash(mesh, req.dirt_map, [s.matrix() for s in req.stations], nozzle, default_robot_model(), params)
    rays = RayCaster(mesh.vertices, mesh.faces) if plan.sweeps else None
    sweeps = []
    for sw in plan.sweeps:
        path = spray_path(sw.T_bin_noz, rays, nozzle)
        sweeps.append(
            PlannedSweep(
                joints=sw.q.tolist(),
                passes=sw.passes,
                region=sw.region,
                station=sw.station,
                faces=sw.faces.tolist(),
                spots=[tuple(p) for p in np.round(path.spots, 5).tolist()],
                axes=[tuple(a) for a in np.round(path.axes, 5).tolist()],
            )
        )
    return WashPlanReply(
        sweeps=sweeps,
        reason=plan.reason,
        dirty=_ids(plan.dirty),
        targets=_ids(plan.targets),
        covered=_ids(plan.covered),
        washed=_ids(plan.washed),
        unwashable=[
            UnwashablePiece(region=u.region, faces=u.faces.tolist(), area_m2=round(u.area_m2, 6), reason=u.reason)
            for u in plan.unwashable
        ],
        summary=plan.summary(mesh),
        plan_s=round(float(plan.times_s.get("total", 0.0)), 3),
        cpu_s=round(float(plan.cpu_s), 3),
    )
