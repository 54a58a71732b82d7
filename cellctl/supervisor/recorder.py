"""What a cycle leaves behind: its MCAP log, its index row and its :class:`CycleResult`.

A :class:`Recorder` is what steps and the dispatcher write to. :class:`CycleRecorder` records
one cycle (MCAP via :class:`~cellctl.recording.cycle_log.CycleLog` plus the index row);
:class:`NullRecorder` stands in outside a cycle (Resetting, Clearing) and writes nothing.
"""

from __future__ import annotations

import datetime as _dt
import json
from abc import ABC, abstractmethod
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellctl.bus import keys
from cellctl.config import CellConfig
from cellctl.hashing import file_sha256_or_none
from cellctl.messages import BinInfo, CycleOutcome, CycleResult, PoseMsg, StationResult, WireMessage
from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.index import CycleIndex

if TYPE_CHECKING:
    from cellctl.supervisor.context import CycleContext

__all__ = ["CycleRecorder", "NullRecorder", "Recorder", "assemble_result", "new_cycle_id"]


class Recorder(ABC):
    """Where a cycle's messages, images and events go (thread-safe in every implementation)."""

    path: Path | None
    """The log file, or None when nothing is written."""
    rel: str | None
    """The log path as the CycleResult names it (relative to the config root)."""

    @abstractmethod
    def write_json(self, topic: str, schema: str, obj: dict[str, Any] | bytes) -> None: ...

    @abstractmethod
    def write_message(self, topic: str, msg: WireMessage) -> None: ...

    @abstractmethod
    def event(self, level: int, text: str) -> None: ...

    @abstractmethod
    def image(self, topic: str, data: bytes, fmt: str, frame_id: str = "camera") -> None: ...

    @abstractmethod
    def close(self, result: CycleResult) -> None:
        """Record the result and close the log and the index row."""


class NullRecorder(Recorder):
    """Recorder of activations outside a cycle: accepts everything, keeps nothing."""

    path = None
    rel = None

    def write_json(self, topic: str, schema: str, obj: dict[str, Any] | bytes) -> None:
        pass

    def write_message(self, topic: str, msg: WireMessage) -> None:
        pass

    def event(self, level: int, text: str) -> None:
        pass

    def image(self, topic: str, data: bytes, fmt: str, frame_id: str = "camera") -> None:
        pass

    def close(self, result: CycleResult) -> None:
        pass


def new_cycle_id(now: _dt.datetime, seq: int) -> str:
    """``YYYYmmddTHHMMSS-mmm-<seq>``: sortable, unique within one supervisor run."""
    return f"{now:%Y%m%dT%H%M%S}-{now.microsecond // 1000:03d}-{seq}"


class CycleRecorder(Recorder):
    """The record of one cycle: opens its index row, then its MCAP (in that order).

    The row first: a crash between the two leaves a row that restart marks interrupted (no log
    yet), never a log that no row accounts for (an orphan to the audit).
    """

    def __init__(self, cfg: CellConfig, index: CycleIndex, cycle_id: str, now: _dt.datetime, mode: str) -> None:
        self.cell_id = cfg.cell_id
        self.index = index
        self.cycle_id = cycle_id
        rel = Path(cfg.recording.dir) / f"{now:%Y-%m-%d}" / f"{cycle_id}.mcap"
        self.rel = str(rel)
        self.path = cfg.path(rel)
        index.begin(cycle_id, cfg.cell_id, str(self.path), now.isoformat(timespec="milliseconds"))
        # What changes the requests a cycle makes beyond its replies is recorded, so that
        # replay --verify re-runs the cycle as it ran (logs without it predate re-looks).
        meta = {
            "cell": cfg.cell_id,
            "mode": mode,
            "relook_max_views": str(cfg.classifier.relook.max_views),
            "relook_confirm_dirty": cfg.classifier.relook.confirm_dirty,
            "whole_bin": str(cfg.planner.whole.enabled).lower(),
            # the verdict's coverage gate (cellctl.seen): replay gates with the minimum the cycle ran with
            "min_seen_fraction": json.dumps(cfg.classifier.verdict.min_seen_fraction, sort_keys=True),
        }
        self._log = CycleLog(self.path, cycle_id, meta)

    def write_json(self, topic: str, schema: str, obj: dict[str, Any] | bytes) -> None:
        self._log.write_json(topic, schema, obj)

    def write_message(self, topic: str, msg: WireMessage) -> None:
        self._log.write_message(topic, msg)

    def event(self, level: int, text: str) -> None:
        self._log.event(level, text)

    def image(self, topic: str, data: bytes, fmt: str, frame_id: str = "camera") -> None:
        self._log.image(topic, data, fmt, frame_id)

    def close(self, result: CycleResult) -> None:
        self._log.write_message(keys.result(self.cell_id), result)
        # the models that decided, in the log's own metadata (readable without decoding a message)
        models = ",".join(result.classifier_models or [])
        paths = ",".join(f"{s}={p}" for s, p in (result.decision_path or {}).items())  # external=references,…
        self._log.close(
            {
                "outcome": result.outcome.value,
                "reason": result.reason or "",
                "classifier_models": models,
                "decision_path": paths,
                "reference_version": str(result.reference_version or ""),
            }
        )
        self.index.finish(
            self.cycle_id,
            result.outcome.value,
            verdict=result.verdict,
            bin_type=result.bin.type,
            plan_id=result.plan_id,
            reason=result.reason,
            log_sha256=file_sha256_or_none(self.path) if self.path is not None else None,
            finished=result.finished,
        )


def assemble_result(ctx: CycleContext, default_outcome: CycleOutcome, reason: str | None = None) -> CycleResult:
    """The CycleResult of a finished cycle from its blackboard (the verdict only when completed)."""
    outcome = ctx.result.outcome or default_outcome
    plan = ctx.scan.plan
    whole = ctx.whole and bool(ctx.stations.station_order)
    return CycleResult(
        cycle_id=ctx.cycle_id,
        outcome=outcome,
        reason=ctx.result.reason or reason,
        bin=BinInfo(
            type=ctx.identity.bin_type,
            pose=PoseMsg.from_matrix(ctx.identity.T_base_bin) if ctx.identity.T_base_bin is not None else None,
        ),
        plan_id=ctx.stations.whole_plan_id if whole else plan.plan_id if plan is not None else None,
        plan_adjusted=(
            any(p.adjusted for p in ctx.stations.plans.values())
            if whole and ctx.stations.plans
            else plan.adjusted
            if plan
            else None
        ),
        planner_job_id=ctx.scan.planner_job_id,
        decision_path=ctx.refs.decision_path,  # type: ignore[arg-type]
        reference_version=ctx.refs.reference_version,
        commission=ctx.refs.commission,
        verdict=ctx.result.verdict if outcome == CycleOutcome.completed else None,
        viewpoints=ctx.scan.viewpoints,
        coverage=ctx.result.coverage,
        dirt_map=ctx.result.dirt_map,
        log=ctx.log_rel,
        timing={
            "steps_s": {k: round(v, 4) for k, v in ctx.step_seconds.items()},
            "rpc_s": {k: round(v, 4) for k, v in ctx.rpc_seconds.items()},
            "rpc_count": ctx.rpc_count,
        },
        started=ctx.started,
        wash=ctx.wash.result,
        whole_plan_id=ctx.stations.whole_plan_id if whole else None,
        coverage_by_surface=ctx.result.coverage_by_surface,
        min_seen_fraction=(
            {k: v for k, v in ctx.cfg.classifier.verdict.min_seen_fraction.items()}
            if outcome == CycleOutcome.completed and ctx.result.verdict is not None
            else None
        ),
        stations=station_results(ctx) if whole else None,
        modelled_cycle_s=ctx.stations.modelled_cycle_s if whole else None,
        classifier_models=classifier_models(ctx),
    )


def classifier_models(ctx: CycleContext) -> list[str] | None:
    """The model ids that decided the cycle's views, re-inspections included (shipped or enrolled)."""
    ids = {v.model_id for v in [*ctx.scan.viewpoints, *ctx.wash.views] if v.model_id}
    return sorted(ids) or None


def station_results(ctx: CycleContext) -> list[StationResult]:
    """What the whole-bin cycle did at each station of its visiting order (also those it never reached)."""
    by_rank = {s.station: s for s in ctx.stations.planned or []}
    out = []
    for pos, rank in enumerate(ctx.stations.station_order):
        st = by_rank[rank]
        plans = {surf: p for (k, surf), p in ctx.stations.plans.items() if k == rank and surf is not None}
        views = [v for v in ctx.scan.viewpoints if v.station == rank and v.relook_of is None]
        reason = ctx.stations.station_notes.get(rank)
        if reason is None and pos > ctx.stations.station_index:
            reason = "not reached: the cycle ended before this station"
        elif reason is None and pos == ctx.stations.station_index and len(plans) < len(st.plans) and ctx.finished:
            reason = "the cycle ended at this station" + (f": {ctx.result.reason}" if ctx.result.reason else "")
        out.append(
            StationResult(
                station=rank,
                base_pose=st.base_pose,
                bin_pose_source=ctx.stations.pose_source.get(rank),  # type: ignore[arg-type]
                plan_ids={s: p.plan_id for s, p in plans.items() if p.plan_id},
                adjusted={s: p.adjusted for s, p in plans.items()},
                viewpoints={s: len(p.viewpoints) for s, p in plans.items()},
                refused={s: sum(1 for v in views if v.surface == s and v.error is not None) for s in plans},
                coverage={s: ctx.stations.station_coverage.get((rank, s)) for s in plans},
                reason=reason,
            )
        )
    return out
