"""reporting: coverage actually seen, the per-face dirt map and (rule ``faces``) the bin verdict.

Views classified by the detector carry a per-patch heat map: it is projected onto the faces
the plan says the view sees, from the pose the camera actually reached, and all views of a face
(re-looks included) are fused into a per-face dirt probability
(:func:`cellctl.classify.heatmap.fuse_views`). Views of a whole-image model paint all their
faces with their ``p_dirty`` (the coarse map of before). The verdict rule is
``classifier.verdict`` (docs/classifier/inspect.md).

A whole-bin cycle's views come from several plans (one per station and surface) and several
base frames: each view's faces come from its own (station, surface) plan and its camera pose is
taken into the bin frame through its own station's bin pose. Coverage is then the area of both
surfaces seen, with each station's share beside it.

Every cycle reports ``coverage_by_surface`` (a single-station cycle too: the surface it did not
inspect is what makes it partial), and a ``clean`` verdict below
``classifier.verdict.min_seen_fraction`` on any surface becomes ``incomplete`` (:mod:`cellctl.seen`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, cast

import numpy as np

from cellctl.bus import topics
from cellctl.messages import CycleOutcome, PlanLookupReply, PoseMsg, ViewpointResult
from cellctl.seen import gate_verdict
from cellctl.supervisor.context import CycleContext, StepRun
from cellctl.supervisor.context.stations import PlanKey
from cellctl.supervisor.steps._base import AT_STATION, Step
from cellctl.supervisor.steps.classifying import view_key
from cellctl.surface import FACE_TAG, SURFACES, Surface

ViewKey = tuple[int | None, str | None, int]


def _faces_by_view(
    plan: PlanLookupReply | None, plans: Mapping[PlanKey, PlanLookupReply] | None
) -> dict[ViewKey, list[int]]:
    """(station, surface, index) → face ids; a single-station cycle's plan is keyed (None, None)."""
    by: Mapping[PlanKey, PlanLookupReply | None] = plans if plans else {(None, None): plan}
    return {
        (st, surf, vp.index): vp.faces for (st, surf), p in by.items() for vp in cast(PlanLookupReply, p).viewpoints
    }


def view_evidence(
    plan: PlanLookupReply | None,
    viewpoints: Sequence[ViewpointResult],
    T_base_bin: np.ndarray | None,
    plans: Mapping[PlanKey, PlanLookupReply] | None = None,
    bin_poses: Mapping[int, np.ndarray] | None = None,
) -> list[Any]:
    """One :class:`~cellctl.classify.heatmap.ViewEvidence` per classified view (re-looks included).

    ``plans`` ((station, surface) → plan) and ``bin_poses`` (station → T_base_bin) serve a whole-bin
    cycle; without them every view is of ``plan``, taken with the bin at ``T_base_bin``.
    """
    from cellctl.classify.heatmap import ViewEvidence, decode_heat

    faces_by = {k: np.asarray(f, np.int64) for k, f in _faces_by_view(plan, plans).items()}
    out = []
    for v in viewpoints:
        if v.error is not None or v.label is None or v.p_dirty is None:
            continue
        faces = faces_by.get(view_key(v), np.zeros(0, np.int64))
        T = (bin_poses or {}).get(v.station, T_base_bin) if v.station is not None else T_base_bin
        T_bin_base = np.linalg.inv(T) if T is not None else None
        heat = decode_heat(v.heatmap, v.heat_grid) if v.heatmap and v.heat_grid else None
        if heat is not None and (v.camera_pose is None or T_bin_base is None):
            heat = None  # no pose to project with: fall back to the view's own probability
        # heat is kept only with a pose and a bin pose to project it with (above)
        T_bin_cam = (
            cast(np.ndarray, T_bin_base) @ cast(PoseMsg, v.camera_pose).matrix() if heat is not None else np.eye(4)
        )
        out.append(ViewEvidence(faces, T_bin_cam, heat, float(v.p_dirty)))
    return out


def dirt_map(
    plan: Any,
    viewpoints: Sequence[ViewpointResult],
    mesh: Any = None,
    surface: Surface | None = "external",
    plans: Mapping[PlanKey, PlanLookupReply] | None = None,
) -> tuple[dict[str, Any], float | None]:
    """The coarse map (no mesh, or no heat maps): each viewpoint's label on the faces it sees.

    A face seen dirty from any viewpoint is dirty; a face seen only clean is clean; a face no
    successful viewpoint saw is unseen. Coverage = area of the inspected surface's faces seen
    / that surface's area (``surface`` None: both surfaces) when the mesh is known, else seen
    faces / mesh faces.
    """
    faces_by = {k: set(f) for k, f in _faces_by_view(plan, plans).items()}
    dirty: set[int] = set()
    seen: set[int] = set()
    for v in viewpoints:
        if v.error is not None or v.label is None:
            continue
        f = faces_by.get(view_key(v), set())
        seen |= f
        if v.label == "dirty":
            dirty |= f
    total = plan.mesh_faces
    coverage = len(seen) / total if total else None
    if mesh is not None:
        total = mesh.n_faces
        coverage = _coverage(mesh, _ids(seen, total), surface)
    return {
        "faces_total": total,
        "seen_dirty": sorted(dirty),
        "seen_clean": sorted(seen - dirty),
        "unseen_count": (total - len(seen)) if total else None,
    }, coverage


def _bin_type(ctx: CycleContext) -> Any:
    """The cycle's bin type (its ID board is an occluder for the heat projection), or None."""
    from cellctl.errors import ConfigError

    try:
        return ctx.catalog.get(ctx.identity.bin_type) if ctx.catalog is not None and ctx.identity.bin_type else None
    except ConfigError:  # the mesh loaded, so this does not happen; without a board the projection still works
        return None


def _ids(faces: set[int], total: int) -> np.ndarray:
    idx = np.fromiter(faces, dtype=np.int64, count=len(faces))
    return idx[(idx >= 0) & (idx < total)]


def _coverage(mesh: Any, seen_ids: np.ndarray, surface: Surface | None) -> float | None:
    """Area fraction of ``surface``'s faces (None: every surface's) among ``seen_ids``."""
    tags = [FACE_TAG[surface]] if surface is not None else [FACE_TAG[s] for s in SURFACES]
    on_surface = np.isin(mesh.surface, tags)
    areas = mesh.areas
    return float(areas[seen_ids][on_surface[seen_ids]].sum() / areas[on_surface].sum()) if on_surface.any() else None


def surface_fractions(mesh: Any, seen_ids: np.ndarray) -> dict[str, float | None]:
    """Area fraction of each surface among the faces ``seen_ids`` (what min_seen_fraction is checked on)."""
    return {s: _coverage(mesh, seen_ids, s) for s in SURFACES}


def gate(run: StepRun, seen: dict[str, float | None] | None) -> None:
    """A ``clean`` verdict below ``classifier.verdict.min_seen_fraction`` on any surface becomes ``incomplete``."""
    ctx = run.ctx
    minimum = cast(Mapping[str, float], ctx.cfg.classifier.verdict.min_seen_fraction)
    ctx.result.verdict, why = gate_verdict(ctx.result.verdict, seen, minimum)
    if why is not None:
        ctx.result.reason = why
        run.event("warning", f"verdict incomplete: {why}")


def _whole_coverage(ctx: CycleContext, mesh: Any, seen: np.ndarray) -> None:
    """Each (station, surface)'s own share of a whole-bin cycle's coverage (``seen``: face ids)."""
    faces_by = {k: set(f) for k, f in _faces_by_view(ctx.scan.plan, ctx.stations.plans).items()}
    for st, surf in ctx.stations.plans:
        mine: set[int] = set()
        for v in ctx.scan.viewpoints:
            if (v.station, v.surface) == (st, surf) and v.error is None and v.label is not None:
                mine |= faces_by.get(view_key(v), set())
        ctx.stations.station_coverage[(st, surf)] = _coverage(
            mesh, _ids(mine, mesh.n_faces), cast(Surface | None, surf)
        )


class Reporting(Step):
    NAME = "reporting"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "per-face dirt map (heat maps fused over views) + coverage; verdict by the configured rule"
    READS = (
        "scan.plan",
        "scan.viewpoints",
        "identity.bin_type",
        "identity.T_base_bin",
        "stations.plans",
        "stations.bin_poses",
        "stations.station_coverage",
        "result.verdict",
    )
    CONSULTS = (*AT_STATION, "result.coverage_by_surface")
    WRITES = (
        "result.dirt_map",
        "result.coverage",
        "result.coverage_by_surface",
        "result.outcome",
        "result.verdict",
        "result.reason",
        "scan.viewpoints",
        "stations.station_coverage",
    )

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        mesh = (
            ctx.catalog.load_mesh(ctx.identity.bin_type) if ctx.catalog is not None and ctx.identity.bin_type else None
        )
        has_heat = any(v.heatmap for v in ctx.scan.viewpoints)
        whole = ctx.whole and bool(ctx.stations.station_order)
        plans = ctx.stations.plans if whole else None
        cover_surface = None if whole else ctx.surface
        if mesh is not None and has_heat and ctx.mode != "collect":
            from cellctl.classify.heatmap import fuse_config, verdict
            from cellctl.geometry.camera import CameraModel

            vc = ctx.cfg.classifier.verdict
            fm = fuse_config(
                view_evidence(
                    ctx.scan.plan, ctx.scan.viewpoints, ctx.identity.T_base_bin, plans, ctx.stations.bin_poses
                ),
                mesh,
                CameraModel.from_config(ctx.cfg.camera),
                vc,
                _bin_type(ctx),
            )
            ctx.result.dirt_map = fm.as_json()
            seen_ids: np.ndarray | None = np.flatnonzero(fm.seen)
            ctx.result.coverage = _coverage(mesh, seen_ids, cover_surface)  # type: ignore[arg-type]
            labels: list[str] = [v.label for v in ctx.scan.viewpoints if v.label is not None]
            if vc.rule == "faces":
                before = ctx.result.verdict
                ctx.result.verdict = verdict(fm, labels, vc.rule, vc.min_dirty_area_cm2)  # type: ignore[assignment]
                run.event(
                    "info",
                    f"verdict {ctx.result.verdict} (rule faces): {int(fm.dirty.sum())} dirty faces, "
                    f"{fm.dirty_area_m2 * 1e4:.1f} cm², {int(fm.seen.sum())} faces seen"
                    + (f"; any-view rule said {before}" if before != ctx.result.verdict else ""),
                )
            # the heat maps are in the MCAP (topics.HEATMAP); the CycleResult keeps face_p
            ctx.scan.viewpoints = [v.model_copy(update={"heatmap": None}) for v in ctx.scan.viewpoints]
        else:
            ctx.result.dirt_map, ctx.result.coverage = dirt_map(
                ctx.scan.plan, ctx.scan.viewpoints, mesh, cover_surface, plans
            )
            seen_ids = (
                _ids(set(ctx.result.dirt_map["seen_dirty"]) | set(ctx.result.dirt_map["seen_clean"]), mesh.n_faces)
                if mesh is not None
                else None
            )
        if mesh is not None and seen_ids is not None:
            ctx.result.coverage_by_surface = surface_fractions(mesh, seen_ids)
        if whole and mesh is not None and seen_ids is not None:
            _whole_coverage(ctx, mesh, seen_ids)
            ctx.result.dirt_map = {**ctx.result.dirt_map, "coverage_by_surface": ctx.result.coverage_by_surface}
            by_surface = ctx.result.coverage_by_surface or {}  # set just above
            run.event(
                "info",
                "whole bin: "
                + ", ".join(f"{s} {c:.0%}" if c is not None else f"{s} -" for s, c in by_surface.items())
                + f" seen from {len(ctx.stations.station_order)} stations",
            )
        if mesh is not None:
            self._scene(ctx, mesh)
        if ctx.mode != "wash_and_verify":  # wash_check gates the verdict the re-inspections end with
            gate(run, ctx.result.coverage_by_surface)
        ctx.result.outcome = CycleOutcome.completed
        return "succeeded"

    @staticmethod
    def _scene(ctx: CycleContext, mesh: Any) -> None:
        """The scan in 3D for Foxglove: bin coloured by the dirt map, one arrow per viewpoint.

        A whole-bin cycle's views of other stations are drawn in the last station's base frame.
        """
        from cellctl.recording import foxglove
        from cellctl.recording.dirt_map import COLOURS, face_colours

        rgba = face_colours(mesh.n_faces, ctx.result.dirt_map or {})  # written by this step before
        cams = []
        for v in ctx.scan.viewpoints:
            if v.camera_pose is None:
                continue
            colour = (
                COLOURS["dirty"] if v.label == "dirty" else COLOURS["clean"] if v.label == "clean" else (0.2, 0.4, 1, 1)
            )
            T = v.camera_pose.matrix()
            T_then = ctx.stations.bin_poses.get(v.station) if v.station is not None else None
            if T_then is not None and ctx.identity.T_base_bin is not None:
                T = ctx.identity.T_base_bin @ np.linalg.inv(T_then) @ T
            cams.append((T, colour, f"{v.index}" + ("r" if v.relook_of is not None else "")))
        ctx.log.write_json(
            topics.SCENE,
            "foxglove.SceneUpdate",
            foxglove.scene_update("base", ctx.identity.T_base_bin, mesh.vertices, mesh.faces, rgba, cams),
        )
