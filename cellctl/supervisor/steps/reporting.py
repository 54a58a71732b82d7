"""reporting: coverage actually seen and the dirt map (faces seen clean / seen dirty / unseen)."""

from __future__ import annotations

import numpy as np

from cellctl.bus import topics
from cellctl.messages import CycleOutcome
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step
from cellctl.surface import FACE_TAG, Surface


def dirt_map(plan, viewpoints, mesh=None, surface: Surface = "external") -> tuple[dict, float | None]:  # noqa: ANN001
    """Project each viewpoint's label onto the faces visible from it.

    A face seen dirty from any viewpoint is dirty; a face seen only clean is clean; a face no
    successful viewpoint saw is unseen. Coverage = area of the inspected surface's faces seen
    / that surface's area when the mesh is known, else seen faces / mesh faces.
    """
    faces_by_index = {vp.index: set(vp.faces) for vp in plan.viewpoints}
    dirty: set[int] = set()
    seen: set[int] = set()
    for v in viewpoints:
        if v.error is not None or v.label is None:
            continue
        f = faces_by_index.get(v.index, set())
        seen |= f
        if v.label == "dirty":
            dirty |= f
    total = plan.mesh_faces
    coverage = len(seen) / total if total else None
    if mesh is not None:
        total = mesh.n_faces
        on_surface = mesh.surface == FACE_TAG[surface]
        areas = mesh.areas
        idx = np.fromiter(seen, dtype=np.int64, count=len(seen))
        idx = idx[(idx >= 0) & (idx < total)]
        coverage = float(areas[idx][on_surface[idx]].sum() / areas[on_surface].sum()) if on_surface.any() else None
    return {
        "faces_total": total,
        "seen_dirty": sorted(dirty),
        "seen_clean": sorted(seen - dirty),
        "unseen_count": (total - len(seen)) if total else None,
    }, coverage


class Reporting(Step):
    NAME = "reporting"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "coverage + dirt map for the CycleResult"
    READS = ("plan", "viewpoints", "params")
    WRITES = ("dirt_map", "coverage", "outcome")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        mesh = ctx.catalog.load_mesh(ctx.bin_type) if ctx.catalog is not None and ctx.bin_type else None
        ctx.dirt_map, ctx.coverage = dirt_map(ctx.plan, ctx.viewpoints, mesh, ctx.surface)
        if mesh is not None:
            self._scene(ctx, mesh)
        ctx.outcome = CycleOutcome.completed
        return "succeeded"

    @staticmethod
    def _scene(ctx, mesh) -> None:  # noqa: ANN001
        """The scan in 3D for Foxglove: bin coloured by the dirt map, one arrow per viewpoint."""
        from cellctl.recording import foxglove
        from cellctl.recording.dirt_map import COLOURS, face_states

        states = face_states(mesh.n_faces, ctx.dirt_map)
        rgba = np.array([COLOURS["unseen"], COLOURS["clean"], COLOURS["dirty"]])[states]
        cams = []
        for v in ctx.viewpoints:
            if v.camera_pose is None:
                continue
            colour = (
                COLOURS["dirty"] if v.label == "dirty" else COLOURS["clean"] if v.label == "clean" else (0.2, 0.4, 1, 1)
            )
            cams.append((v.camera_pose.matrix(), colour, f"{v.index}"))
        ctx.log.write_json(
            topics.SCENE,
            "foxglove.SceneUpdate",
            foxglove.scene_update("base", ctx.T_base_bin, mesh.vertices, mesh.faces, rgba, cams),
        )
