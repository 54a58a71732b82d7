"""references: what the cycle's views were judged against; in a commissioning cycle, the reference set.

Every cycle passes here after its last classification, before reporting.

* **Reference query** (:func:`reference_query`, called by the scan for every view outside a
  commissioning cycle): the viewpoint's stored reference in the newest set of the bin type holding
  the plan (:mod:`cellctl.recording.references`), both camera poses in the bin frame and the viewed
  plane; the classifier worker compares the view with it and says which path decided.
* **Decision path** per surface (``CycleResult.decision_path``): ``references`` when views of the
  surface were decided against their references (``ViewpointResult.decided_by``); else ``enrolled``
  when a site-enrolled detector (model id ``<surface>-enrolled-…``) decided a view of it; else
  ``shipped``. A replan makes a new plan id, which no set holds until it is commissioned. The
  per-path counts and the reasons a reference did not decide go into the record
  (:func:`decision_counts`). A commissioning cycle's own path is computed before its set exists: its views
  were judged without it.
* **Commissioning** (Start ``mode=commission``; :func:`store_reference` kept each view during the
  scan): the set is given the bin type's next version, the classifier worker enrolls each surface's
  detector from that surface's views into ``<set>/<surface>.enrolled.pt`` (and decides with it from
  then on), the manifest is written, and the manifest with its sha256 goes into the cycle's MCAP —
  so the index row's chained log hash vouches for the set (``cellctl audit verify``). A surface the
  worker cannot enroll (too few views, images that score like dirt, no worker) keeps its detector
  and is named in ``CommissionResult.problems``; the references are stored all the same.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import numpy as np

from cellctl.bus import topics
from cellctl.errors import RecordingError, WorkerError
from cellctl.messages import ClassifyReference, CommissionResult, EnrollReply, EnrollRequest, Intrinsics, PoseMsg
from cellctl.recording.references import (
    ReferenceManifest,
    ReferenceSetWriter,
    enrolled_file,
    latest_set,
    reference_in,
    reference_root,
)
from cellctl.supervisor.context import CycleContext, StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step
from cellctl.surface import Surface

__all__ = [
    "ENROLL_TIMEOUT_S",
    "References",
    "decision_counts",
    "decision_paths",
    "reference_query",
    "reference_set",
    "reference_state",
    "store_reference",
]

ENROLL_TIMEOUT_S = 1800.0
"""How long one surface's enrollment may take on the classifier worker: a whole-bin plan gives it
~80 views, each with synthetic dirty versions through the network, on a CPU shared with the cell."""


def store_reference(
    ctx: CycleContext, viewpoint: int, image: bytes, fmt: str, T_base_cam: np.ndarray, intr: Intrinsics | None
) -> None:
    """The scan's hook in a commissioning cycle: this view (as the classifier sees it) becomes the
    reference of its viewpoint in the plan scanned now.

    Raises:
        RecordingError: the image cannot be stored (the cycle fails: a set with holes is not one).
    """
    plan = ctx.scan.plan
    if plan is None or ctx.identity.bin_type is None:
        raise RecordingError("a commissioning view came before the bin type and plan were known")
    if ctx.refs.writer is None:
        ctx.refs.writer = ReferenceSetWriter(reference_root(ctx.cfg), ctx.identity.bin_type, ctx.cycle_id)
    st = ctx.stations.current_station()
    ctx.refs.writer.add(
        plan.plan_id or "unnamed",
        ctx.surface,
        st.station if st is not None else None,
        viewpoint,
        image,
        fmt,
        T_base_cam,
        ctx.identity.T_base_bin,
        intr,
    )


def reference_set(ctx: CycleContext, plan_id: str) -> tuple[ReferenceManifest, Path] | None:
    """The newest complete set of the cycle's bin type holding ``plan_id``, resolved once per plan and cycle
    (``ctx.refs.sets``: the manifests are read and parsed at the plan's first view, not at every view)."""
    assert ctx.identity.bin_type is not None
    if plan_id not in ctx.refs.sets:
        ctx.refs.sets[plan_id] = latest_set(reference_root(ctx.cfg), ctx.identity.bin_type, plan_id)
    return ctx.refs.sets[plan_id]


def reference_query(ctx: CycleContext, viewpoint: int, T_base_cam: np.ndarray) -> ClassifyReference | None:
    """What the scan asks the classifier to compare a view with: the viewpoint's stored reference in
    the newest set holding the plan scanned now, both cameras in the bin frame of their own cycle,
    and the viewed plane from the mesh at the reference pose. None when the plan has no set, the
    set has no reference for this viewpoint (refused while commissioning) or a pose, the intrinsics
    or the mesh's plane is missing, or ``classifier.references`` is off: the detector decides alone
    (:func:`reference_state` says why).
    """
    plan = ctx.scan.plan
    if plan is None or ctx.identity.bin_type is None or ctx.identity.T_base_bin is None or ctx.catalog is None:
        return None
    if not ctx.cfg.classifier.references:  # switched off: the detector alone, as before commissioning
        return None
    plan_id = plan.plan_id or "unnamed"
    ref = reference_in(reference_set(ctx, plan_id), plan_id, viewpoint)
    if ref is None or ref.T_bin_cam is None or ref.intrinsics is None:
        return None
    from cellctl.classify.reference import plane_from_mesh
    from cellctl.errors import ClassifierError

    mesh = ctx.catalog.load_mesh(ctx.identity.bin_type)
    if ctx.refs.caster is None:  # one bin type per cycle (identifying refuses another)
        from cellctl.classify.heatmap import MeshCaster

        ctx.refs.caster = MeshCaster(mesh)
    intr = ref.intrinsics
    try:
        plane = plane_from_mesh(ctx.refs.caster, mesh, ref.T_bin_cam, intr.K(), intr.width, intr.height)
    except ClassifierError:
        return None
    T_bin_cam = np.linalg.inv(ctx.identity.T_base_bin) @ np.asarray(T_base_cam, np.float64)
    return ClassifyReference(
        image=str(ref.image),
        sha256=ref.sha256,
        version=ref.version,
        reference_pose=PoseMsg.from_matrix(ref.T_bin_cam, "bin"),
        view_pose=PoseMsg.from_matrix(T_bin_cam, "bin"),
        intrinsics=intr,
        plane_normal=plane.normal,
        plane_distance=plane.distance,
    )


def reference_state(ctx: CycleContext) -> str | None:
    """For a view sent without a reference: ``no_reference`` when the plan scanned now has a set
    (the viewpoint has none in it), None when it has none (the plan was never commissioned)."""
    if ctx.scan.plan is None or ctx.identity.bin_type is None or not ctx.cfg.classifier.references:
        return None
    found = reference_set(ctx, ctx.scan.plan.plan_id or "unnamed")
    return "no_reference" if found is not None else None


def _scanned_plans(ctx: CycleContext) -> dict[str, list[str]]:
    """surface → the plan ids the cycle scanned for it."""
    out: dict[str, list[str]] = {}
    for (_station, surface), reply in ctx.stations.plans.items():
        out.setdefault(surface or ctx.surface, []).append(reply.plan_id or "unnamed")
    return out


def decision_counts(ctx: CycleContext) -> dict[str, dict[str, int]]:
    """Per surface, how many classified views each path decided (``reference``, ``detector``, ``model``)
    and, for views whose plan had references, why the detector decided alone (``<reason>``)."""
    out: dict[str, dict[str, int]] = {}
    for v in ctx.scan.viewpoints:
        if v.label is None:
            continue
        c = out.setdefault(v.surface or ctx.surface, {})
        key = v.decided_by or "detector"
        c[key] = c.get(key, 0) + 1
        if v.reference_reason not in (None, "aligned"):
            c[str(v.reference_reason)] = c.get(str(v.reference_reason), 0) + 1
    return out


def decision_paths(ctx: CycleContext) -> tuple[dict[str, str] | None, int | None]:
    """Per surface, what its views were judged against, and the newest reference set version used.

    ``references`` only where views were decided with the comparison against their reference
    (``ViewpointResult.decided_by == 'reference'``): a set that holds the plan is not enough — the
    views of a viewpoint without a reference, past the pose tolerance or whose alignment was
    rejected were judged by the detector alone, and :func:`decision_counts` records how many.
    """
    if ctx.identity.bin_type is None or not ctx.stations.plans:
        return None, None
    paths: dict[str, str] = {}
    version = None
    for surface, plan_ids in _scanned_plans(ctx).items():
        mine = [v for v in ctx.scan.viewpoints if (v.surface or ctx.surface) == surface]
        if any(v.decided_by == "reference" for v in mine):
            paths[surface] = "references"
            found = [reference_set(ctx, pid) for pid in plan_ids]
            version = max([version or 0, *(f[0].version for f in found if f is not None)]) or None
            continue
        enrolled = any("-enrolled-" in (v.model_id or "") for v in mine)
        paths[surface] = "enrolled" if enrolled else "shipped"
    return paths, version


def _enroll(run: StepRun, folder: Path, surface: Surface) -> tuple[EnrollReply | None, str | None]:
    """Ask the classifier worker to enroll ``surface`` from the set's views of it: (reply, None) or (None, why)."""
    req = EnrollRequest(surface=surface, images=str(folder / surface), out=str(folder / f"{surface}.enrolled.pt"))
    try:
        reply, _ = run.call("classifier", "enroll", req, EnrollReply, timeout=ENROLL_TIMEOUT_S)
    except WorkerError as err:
        return None, str(err)
    return reply, None


def commission(run: StepRun, record: dict[str, Any]) -> CommissionResult:
    """Close a commissioning cycle's reference set: version, enrolled detectors, manifest, audit record
    (``record`` plus the manifest and its sha256, on :data:`~cellctl.bus.topics.REFERENCES`).

    Raises:
        RecordingError: no view was stored, or the set cannot be written.
    """
    ctx = run.ctx
    refs = ctx.refs.writer
    if refs is None:
        raise RecordingError("the commissioning cycle stored no reference view (every viewpoint refused?)")
    folder = refs.claim()
    enrolled, problems = {}, {}
    for surface in refs.surfaces():
        reply, why = _enroll(run, folder, cast(Surface, surface))  # stored under the scan's surfaces
        entry = enrolled_file(folder, surface, reply.model_id) if reply is not None else None
        if reply is not None and entry is None:
            why = f"the classifier worker reported {reply.path} written, but {folder}/{surface}.enrolled.pt is missing"
        elif entry is not None and reply is not None and entry.sha256 != reply.sha256:
            why, entry = f"{entry.file} has sha256 {entry.sha256}, the worker wrote {reply.sha256}", None
        if entry is not None:
            enrolled[surface] = entry
        else:
            problems[surface] = why or "not enrolled"
            run.event("warning", f"commissioning: {surface} detector not enrolled: {problems[surface]}")
    man, path, sha = refs.finish(ctx.user or "", ctx.stations.whole_plan_id, enrolled, problems)
    record = {**record, "manifest_sha256": sha, "manifest_path": str(path), "manifest": man.model_dump(mode="json")}
    ctx.log.write_json(topics.REFERENCES, "cellctl.References", record)
    run.event("info", f"commissioning: reference set v{man.version} of {man.bin_type}, {man.references} views")
    rel = path.relative_to(ctx.cfg.root) if path.is_relative_to(ctx.cfg.root) else path
    return CommissionResult(
        bin_type=man.bin_type,
        version=man.version,
        manifest=str(rel),
        manifest_sha256=sha,
        references=man.references,
        plan_ids=sorted(man.plans),
        declared_by=man.declared_by,
        enrolled={s: str(folder / e.file) for s, e in enrolled.items()},  # type: ignore[misc]
        problems=problems,
    )


class References(Step):
    NAME = "references"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "decision path per surface; mode commission: version the reference set, enroll, manifest, audit"
    READS = ("scan.viewpoints", "stations.plans", "identity.bin_type", "refs.sets")
    CONSULTS = (*AT_STATION, "refs.writer", "stations.whole_plan_id")
    WRITES = ("refs.decision_path", "refs.reference_version", "refs.commission", "refs.sets")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        ctx.refs.decision_path, ctx.refs.reference_version = decision_paths(ctx)  # type: ignore[assignment]
        counts = decision_counts(ctx)
        record = {
            "decision_path": ctx.refs.decision_path,
            "reference_version": ctx.refs.reference_version,
            "decided_by": counts,
        }
        for surface, c in counts.items():
            if ctx.refs.decision_path and ctx.refs.decision_path.get(surface) != "references" and c.get("detector"):
                why = {k: n for k, n in c.items() if k not in ("reference", "detector", "model")}
                if why:  # the plan had references, yet none decided a view: say why in the event log
                    run.event("warning", f"{surface}: no view was judged against its reference ({why})")
        if ctx.mode == "commission":
            ctx.refs.commission = commission(run, record)
        else:
            ctx.log.write_json(topics.REFERENCES, "cellctl.References", record)
        return "succeeded"
