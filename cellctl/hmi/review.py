"""Operator review in the HMI: the queue of uncertain and dirty views, decisions, release gating.

* **Queue**: every view of a completed cycle (newest ``review.queue_cycles``) that the classifier
  called dirty or uncertain. An item is ``<cycle id>/<image n>`` (``n``: the view's image in the
  cycle's log, as in ``/api/cycles/{id}/images/{n}``).
* **Decision**: an ``operator`` or ``qa`` user confirms the view *clean* or *dirty* with a reason.
  It is appended to the review ledger (:mod:`cellctl.review.ledger`: user, role, time, the image's
  sha256 and the cycle's index row hash, hash-chained), and the view goes into the review bank
  (:mod:`cellctl.review.bank`) under its label. A view is decided once: a second decision is
  refused (the ledger would hold two answers to one question).
* **Release**: a completed cycle with an uncertain view (``review.require_for_uncertain``) is
  released only by review: every uncertain view decided, then Release by an operator or qa user
  (a ledger entry). Other completed cycles stand released as recorded (``auto``). The released
  verdict applies the decisions: a view confirmed dirty makes the bin dirty; a dirty verdict whose
  dirty views were all confirmed clean becomes clean; ``incomplete`` stays incomplete otherwise
  (what was not seen cannot be reviewed).
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from cellctl.config import CellConfig
from cellctl.errors import CellError
from cellctl.hashing import bytes_sha256
from cellctl.hmi.records import CycleFilter, CycleRecords, NotFound
from cellctl.review.bank import open_bank
from cellctl.review.ledger import LEDGER_NAME, Ledger

__all__ = ["REVIEWERS", "Conflict", "Review"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

REVIEWERS = ("operator", "qa")
"""The HMI roles that may confirm a view and release a verdict (a ``viewer`` only reads)."""


class Conflict(CellError):
    """The request is well-formed but the record's state refuses it (decided already, gate closed …)."""


class Review:
    """The review of one cell's records (module doc).

    Args:
        records: the HMI's read-only view of the index and logs.
    """

    def __init__(self, cfg: CellConfig, records: CycleRecords) -> None:
        self.cfg, self.records = cfg, records
        self.ledger = Ledger(cfg.path(cfg.recording.dir) / LEDGER_NAME)
        self.bank = open_bank(cfg)
        # one decision or release at a time: two operators answering the same view at once must not
        # both pass the "not decided yet" check (the routes run in a thread pool)
        self._decide = threading.Lock()

    # --- the queue ----------------------------------------------------------------------------

    def _views(self, cycle_id: str, files: bool = False) -> tuple[dict[str, Any], list[dict[str, Any]]]:
        """The cycle's record and its reviewable views (dirty or uncertain), with surface and decision
        (``files``: with the reference's server path, never sent to a client)."""
        d = self.records.detail(cycle_id)
        res = d["result"] or {}
        if d["row"]["outcome"] != "completed" or not res:
            return d, []
        by_index = {v.get("index"): v for v in res.get("viewpoints", []) if v.get("error") is None}
        decided = {e["image"]: e for e in self.ledger.of_cycle(cycle_id) if e.get("kind") == "decision"}
        default_surface = res.get("surface") or self.cfg.planner.surface
        out = []
        for img in d["images"]:
            if img.get("label") != "dirty" and not img.get("uncertain"):
                continue
            v = by_index.get(img.get("index"), {})
            e = decided.get(img["image"])
            ref = self._reference(res, v, v.get("surface") or default_surface)
            if ref is not None and not files:
                ref = {k: x for k, x in ref.items() if k != "_file"}
            out.append({
                "id": f"{cycle_id}/{img['image']}",
                "cycle_id": cycle_id,
                "image": img["image"],
                "viewpoint": img.get("index"),
                "surface": v.get("surface") or default_surface,
                "station": v.get("station"),
                "label": img.get("label"),
                "p_dirty": img.get("p_dirty"),
                "uncertain": bool(img.get("uncertain")),
                "why": "uncertain" if img.get("uncertain") else "dirty",
                "model_id": v.get("model_id"),
                "heatmap": img.get("heatmap") is not None,
                # the reference image of this viewpoint, when the cycle was judged against a commissioned set
                "reference": ref,
                "faces": v.get("faces"),
                "bin_picture": bool(res.get("dirt_map")),
                "bin_type": (res.get("bin") or {}).get("type") or d["row"].get("bin_type"),
                "finished": d["row"].get("finished"),
                "decision": _public(e) if e else None,
            })  # fmt: skip
        return d, out

    def _reference(self, res: dict[str, Any], v: dict[str, Any], surface: str) -> dict[str, Any] | None:
        """Which reference the view was compared with: the set version the CycleResult names, the plan
        the view's station scanned for its surface, its viewpoint; None when the surface was not judged
        against references (not commissioned, or a replan since) or the set no longer holds it."""
        from cellctl.recording.references import MANIFEST, read_manifest, reference_root, set_versions

        version, bin_type = res.get("reference_version"), (res.get("bin") or {}).get("type")
        if not version or not bin_type or (res.get("decision_path") or {}).get(surface) != "references":
            return None
        station = next((s for s in res.get("stations") or [] if s.get("station") == v.get("station")), None)
        plan_id = (station or {}).get("plan_ids", {}).get(surface) if station else res.get("plan_id")
        folder = next((f for ver, f in set_versions(reference_root(self.cfg), bin_type) if ver == version), None)
        if folder is None or plan_id is None:
            return None
        try:
            man = read_manifest(folder / MANIFEST)
        except CellError as err:  # the audit names a damaged set; the review shows no reference
            log.warning("reference set %s: %s", folder, err)
            return None
        plan = man.plans.get(plan_id)
        view = plan.views.get(v.get("index", -1)) if plan is not None else None
        if view is None:
            return None
        return {"version": version, "plan_id": plan_id, "viewpoint": view.viewpoint, "sha256": view.sha256,
                "declared_by": man.declared_by, "commissioned_in": man.cycle_id,
                "_file": str(folder / view.image)}  # fmt: skip

    def reference_image(self, cycle_id: str, n: int) -> bytes:
        """The reference image of queue item ``cycle_id/n``, checked against its manifest's sha256.

        Raises:
            NotFound: the view has no reference. RecordingError: the file differs from its manifest.
        """
        from pathlib import Path

        from cellctl.errors import RecordingError
        from cellctl.recording.references import reference_root

        _, views = self._views(cycle_id, files=True)
        ref = next((v["reference"] for v in views if v["image"] == n), None)
        if ref is None:
            raise NotFound(f"view {cycle_id}/{n} has no reference (its plan was not commissioned)")
        p, root = Path(ref["_file"]).resolve(), reference_root(self.cfg).resolve()
        data = p.read_bytes() if p.is_relative_to(root) and p.is_file() else b""
        if bytes_sha256(data) != ref["sha256"]:
            raise RecordingError(f"reference of view {cycle_id}/{n} is missing or differs from its set's manifest")
        return data

    def queue(self, state: str = "open", limit: int = 100) -> list[dict[str, Any]]:
        """Reviewable views of the newest completed cycles, newest cycle first.

        Args:
            state: ``open`` (not decided yet), ``decided`` or ``all``.
        """
        if state not in ("open", "decided", "all"):
            raise ValueError(f"state={state!r} is unknown; expected one of ['open', 'decided', 'all']")
        rows = self.records.cycles(CycleFilter(outcome="completed", limit=self.cfg.review.queue_cycles))
        items: list[dict[str, Any]] = []
        for r in rows:
            try:
                _, views = self._views(r["cycle_id"])
            except (NotFound, CellError) as err:  # a damaged log must not hide the rest of the queue
                log.warning("review queue: cycle %s skipped: %s", r["cycle_id"], err)
                continue
            items += [v for v in views if state == "all" or (v["decision"] is None) == (state == "open")]
            if len(items) >= limit:
                break
        return items[:limit]

    def item(self, cycle_id: str, n: int) -> dict[str, Any]:
        """One queue item with the cycle's release state.

        Raises:
            NotFound: no such cycle, or image ``n`` is not a dirty or uncertain view of a completed cycle.
        """
        _, views = self._views(cycle_id)
        it = next((v for v in views if v["image"] == n), None)
        if it is None:
            raise NotFound(f"image {n} of cycle {cycle_id!r} is not a dirty or uncertain view of a completed cycle")
        return {**it, "release": self.release_state(cycle_id)}

    # --- decisions ----------------------------------------------------------------------------

    def decide(self, cycle_id: str, n: int, label: str, reason: str, user: str, role: str) -> dict[str, Any]:
        """Record a decision (ledger) and bank the view; returns the decision, the bank entry and release state.

        Raises:
            NotFound: not a queue item. Conflict: already decided, or the cycle was released.
            RecordingError: the ledger or the bank cannot be written.
        """
        with self._decide:
            return self._decide_locked(cycle_id, n, label, reason, user, role)

    def _decide_locked(self, cycle_id: str, n: int, label: str, reason: str, user: str, role: str) -> dict[str, Any]:
        it = self.item(cycle_id, n)
        if it["decision"] is not None:
            d = it["decision"]
            raise Conflict(f"view {it['id']} was confirmed {d['label']} by {d['user']} at {d['time']}; a view is "
                           "decided once")  # fmt: skip
        if it["release"]["state"] == "released":
            raise Conflict(f"cycle {cycle_id!r} was released by {it['release']['released_by']}; its views are closed")
        data, fmt = self.records.image(cycle_id, n)
        row = self.records.row(cycle_id)
        entry = self.ledger.append(
            "decision", cycle_id, row.row_hash, user, role, image=n, viewpoint=it["viewpoint"],
            surface=it["surface"], label=label, reason=reason, classifier={"label": it["label"],
            "p_dirty": it["p_dirty"], "uncertain": it["uncertain"], "model_id": it["model_id"]},
            image_sha256=bytes_sha256(data),
        )  # fmt: skip
        banked = self.bank.add(it["surface"], label, data, fmt, {  # type: ignore[arg-type]  # checked by the API model
            "cycle_id": cycle_id, "image": n, "viewpoint": it["viewpoint"], "user": user, "role": role,
            "time": entry["time"], "reason": reason, "decision_hash": entry["entry_hash"]})  # fmt: skip
        counts = self.bank.counts().get(it["surface"], {"clean": 0, "dirty": 0})
        return {"decision": _public(entry), "bank": {"file": banked["file"], "surface": it["surface"],
                "label": label, "counts": counts, "evicted": banked["evicted"]},
                "release": self.release_state(cycle_id)}  # fmt: skip

    # --- release --------------------------------------------------------------------------------

    def release_state(self, cycle_id: str) -> dict[str, Any]:
        """Whether the cycle's verdict is released, and why not (module doc).

        ``state``: ``not_applicable`` (no verdict: not a completed cycle), ``auto`` (released as
        recorded: no uncertain view, or gating off), ``review_required`` (uncertain views undecided),
        ``ready`` (all decided: Release may be pressed), ``released`` (by review).
        """
        d, views = self._views(cycle_id)
        verdict = d["row"].get("verdict")
        required = self.cfg.review.require_for_uncertain
        uncertain = [v for v in views if v["uncertain"]]
        open_ = [v["image"] for v in uncertain if v["decision"] is None]
        rel = next((e for e in reversed(self.ledger.of_cycle(cycle_id)) if e.get("kind") == "release"), None)
        out: dict[str, Any] = {"cycle_id": cycle_id, "verdict": verdict, "required": required,
                               "uncertain_views": len(uncertain), "open_uncertain": open_,
                               "decided": sum(v["decision"] is not None for v in views),
                               "reviewed_verdict": reviewed_verdict(verdict, views),
                               "released_verdict": None, "released_by": None, "released_at": None}  # fmt: skip
        if d["row"]["outcome"] != "completed":
            return {**out, "state": "not_applicable"}
        if rel is not None:
            return {**out, "state": "released", "released_verdict": rel.get("verdict"), "released_by": rel["user"],
                    "released_at": rel["time"], "release_hash": rel["entry_hash"]}  # fmt: skip
        if not uncertain or not required:
            return {**out, "state": "auto", "released_verdict": verdict}
        return {**out, "state": "ready" if not open_ else "review_required"}

    def release(self, cycle_id: str, user: str, role: str, reason: str) -> dict[str, Any]:
        """Release the cycle's reviewed verdict (a ledger entry).

        Raises:
            Conflict: nothing to release (auto, not a completed cycle, released already) or uncertain
                views still undecided (named).
        """
        with self._decide:
            return self._release_locked(cycle_id, user, role, reason)

    def _release_locked(self, cycle_id: str, user: str, role: str, reason: str) -> dict[str, Any]:
        st = self.release_state(cycle_id)
        if st["state"] == "review_required":
            raise Conflict(f"cycle {cycle_id!r} has {len(st['open_uncertain'])} uncertain view(s) not reviewed yet "
                           f"(images {st['open_uncertain']}); confirm each clean or dirty first")  # fmt: skip
        if st["state"] != "ready":
            why = {
                "auto": "its verdict stands released as recorded (no uncertain view, or review.require_for_"
                "uncertain is false)",
                "released": f"it was released by {st['released_by']} at {st['released_at']}",
                "not_applicable": "it is not a completed cycle (no verdict)",
            }[st["state"]]
            raise Conflict(f"cycle {cycle_id!r} cannot be released: {why}")
        row = self.records.row(cycle_id)
        self.ledger.append("release", cycle_id, row.row_hash, user, role, verdict=st["reviewed_verdict"],
                           recorded_verdict=st["verdict"], reason=reason)  # fmt: skip
        return self.release_state(cycle_id)


def reviewed_verdict(verdict: str | None, views: list[dict[str, Any]]) -> str | None:
    """The bin's verdict with the decisions applied (module doc)."""
    decided = [v for v in views if v["decision"] is not None]
    if any(v["decision"]["label"] == "dirty" for v in decided):
        return "dirty"
    if verdict == "dirty":
        dirty = [v for v in views if v["label"] == "dirty"]
        if dirty and all(v["decision"] is not None and v["decision"]["label"] == "clean" for v in dirty):
            return "clean"
    return verdict


def _public(e: dict[str, Any]) -> dict[str, Any]:
    """A ledger entry as the API shows it."""
    keys = ("seq", "kind", "label", "reason", "user", "role", "time", "entry_hash", "image", "surface", "verdict")
    return {k: e[k] for k in keys if k in e}
