"""reporting: coverage actually seen, the per-face dirt map and (rule ``faces``) the bin verdict.

Views classified by the detector carry a per-patch heat map: it is projected onto the faces
the plan says the view sees, from the pose the camera actually reached, and all views of a face
(re-looks included) are fused into a per-face dirt probability
(:func:`cellctl.classify.heatmap.fuse_views`). Views of a whole-image model paint all their
faces with their ``p_dirty`` (the coarse map of before). The verdict rule is
``classifier.verdict`` (docs/classifier/inspect.md).
"""

from __future__ import annotations

import numpy as np

from cellctl.bus import topics
from cellctl.messages import CycleOutcome
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step
from cellctl.surface import FACE_TAG, Surface


def view_evidence(plan, viewpoints, T_base_bin) -> list:  # noqa: ANN001
    """One :class:`~cellctl.classify.heatmap.ViewEvidence` per classified view (re-looks included)."""
    from cellctl.classify.heatmap import ViewEvidence, decode_heat

    faces_by_index = {vp.index: np.asarray(vp.faces, np.int64) for vp in plan.viewpoints}
    T_bin_base = np.linalg.inv(T_base_bin) if T_base_bin is not None else None
    out = []
    for v in viewpoints:
        if v.error is not None or v.label is None or v.p_dirty is None:
            continue
        faces = faces_by_index.get(v.index, np.zeros(0, np.int64))
        heat = decode_heat(v.heatmap, v.heat_grid) if v.heatmap and v.heat_grid else None
        if heat is not None and (v.camera_pose is None or T_bin_base is None):
            heat = None  # no pose to project with: fall back to the view's own probability
        T_bin_cam = T_bin_base @ v.camera_pose.matrix() if heat is not None else np.eye(4)
        out.append(ViewEvidence(faces, T_bin_cam, heat, float(v.p_dirty)))
    return out


def dirt_map(plan, viewpoints, mesh=None, surface: Surface = "external") -> tuple[dict, float | None]:  # noqa: ANN001
    """The coarse map (no mesh, or no heat maps): each viewpoint's label on the faces it sees.

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
        idx = np.fromiter(seen, dtype=np.int64, count=len(seen))
        coverage = _coverage(mesh, idx[(idx >= 0) & (idx < total)], surface)
    return {
        "faces_total": total,
        "seen_dirty": sorted(dirty),
        "seen_clean": sorted(seen - dirty),
        "unseen_count": (total - len(seen)) if total else None,
    }, coverage


def _coverage(mesh, seen_ids: np.ndarray, surface: Surface) -> float | None:  # noqa: ANN001
    on_surface = mesh.surface == FACE_TAG[surface]
    areas = mesh.areas
    return float(areas[seen_ids][on_surface[seen_ids]].sum() / areas[on_surface].sum()) if on_surface.any() else None


class Reporting(Step):
    NAME = "reporting"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "per-face dirt map (heat maps fused over views) + coverage; verdict by the configured rule"
    READS = ("plan", "viewpoints", "params")
    WRITES = ("dirt_map", "coverage", "outcome", "verdict", "viewpoints")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        mesh = ctx.catalog.load_mesh(ctx.bin_type) if ctx.catalog is not None and ctx.bin_type else None
        has_heat = any(v.heatmap for v in ctx.viewpoints)
        if mesh is not None and has_heat and ctx.mode != "collect":
            from cellctl.classify.heatmap import fuse_views, verdict
            from cellctl.geometry.camera import CameraModel

            vc = ctx.cfg.classifier.verdict
            fm = fuse_views(
                view_evidence(ctx.plan, ctx.viewpoints, ctx.T_base_bin),
                mesh,
                CameraModel.from_config(ctx.cfg.camera),
                prior=vc.face_prior,
                face_threshold=vc.face_threshold,
            )
            ctx.dirt_map = fm.as_json()
            ctx.coverage = _coverage(mesh, np.flatnonzero(fm.seen), ctx.surface)
            labels = [v.label for v in ctx.viewpoints if v.label is not None]
            if vc.rule == "faces":
                before = ctx.verdict
                ctx.verdict = verdict(fm, labels, vc.rule, vc.min_dirty_area_cm2)  # type: ignore[assignment]
                run.event(
                    "info",
                    f"verdict {ctx.verdict} (rule faces): {int(fm.dirty.sum())} dirty faces, "
                    f"{fm.dirty_area_m2 * 1e4:.1f} cm², {int(fm.seen.sum())} faces seen"
                    + (f"; any-view rule said {before}" if before != ctx.verdict else ""),
                )
            # the heat maps are in the MCAP (topics.HEATMAP); the CycleResult keeps face_p
            ctx.viewpoints = [v.model_copy(update={"heatmap": None}) for v in ctx.viewpoints]
        else:
            ctx.dirt_map, ctx.coverage = dirt_map(ctx.plan, ctx.viewpoints, mesh, ctx.surface)
        if mesh is not None:
            self._scene(ctx, mesh)
        ctx.outcome = CycleOutcome.completed
        return "succeeded"

    @staticmethod
    def _scene(ctx, mesh) -> None:  # noqa: ANN001
        """The scan in 3D for Foxglove: bin coloured by the dirt map, one arrow per viewpoint."""
        from cellctl.recording import foxglove
        from cellctl.recording.dirt_map import COLOURS, face_colours

        rgba = face_colours(mesh.n_faces, ctx.dirt_map)
        cams = []
        for v in ctx.viewpoints:
            if v.camera_pose is None:
                continue
            colour = (
                COLOURS["dirty"] if v.label == "dirty" else COLOURS["clean"] if v.label == "clean" else (0.2, 0.4, 1, 1)
            )
            cams.append((v.camera_pose.matrix(), colour, f"{v.index}" + ("r" if v.relook_of is not None else "")))
        ctx.log.write_json(
            topics.SCENE,
            "foxglove.SceneUpdate",
            foxglove.scene_update("base", ctx.T_base_bin, mesh.vertices, mesh.faces, rgba, cams),
        )
