"""``cellctl bench soak --cycles N``: sim cycles back to back; cycles/hour, RSS, open files, threads,
and the viewpoints the arm refused (``refused_viewpoints``, per cycle in ``refused_by_cycle``).

The whole cell runs as in production (daemon in this process, the four sim workers as child
processes); a PLC client runs Reset → Start → result with zero settle and no pause between
cycles. Every few cycles it samples, for the daemon and each worker: resident memory, open
file descriptors (files, sockets, pipes) and threads. Growth is judged after a warm-up (first
10 % of the samples, where caches and allocator pools fill): the median of the last fifth of
the samples minus the median of the first fifth after warm-up, against a noise floor.

The sim runs fast (:data:`cellctl.bench.reliability.sim_cell.FAST_SIM`) because the soak is about
the controller's resources over many cycles, not about motion time; ``--set`` changes that.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path
from typing import Any

from cellctl.bench.options import BenchOptions

__all__ = ["ResourceSampler", "bench_soak", "growth", "refused_viewpoints"]

GROWTH_FLOOR = {"rss_mb": 5.0, "fds": 2.0, "threads": 2.0}
"""Absolute growth below which a change is noise (allocator pools, a lazily opened file)."""


class ResourceSampler:
    """Samples RSS, open fds and threads of named processes (this one and child workers)."""

    def __init__(self, pids: dict[str, int]) -> None:
        import psutil

        self._procs = {name: psutil.Process(pid) for name, pid in pids.items()}
        self.samples: list[dict[str, Any]] = []

    def sample(self, cycle: int, t_s: float) -> dict[str, Any]:
        row: dict[str, Any] = {"cycle": cycle, "t_s": round(t_s, 1)}
        for name, p in self._procs.items():
            try:
                with p.oneshot():
                    row[name] = {
                        "rss_mb": round(p.memory_info().rss / 2**20, 2),
                        "fds": p.num_fds(),
                        "threads": p.num_threads(),
                    }
            except Exception as err:  # a worker that died is a finding, not a crash of the bench
                row[name] = {"error": f"{type(err).__name__}: {err}"}
        self.samples.append(row)
        return row


def growth(samples: list[dict[str, Any]], name: str, metric: str) -> dict[str, Any]:
    """Growth of ``metric`` of process ``name`` after warm-up, with its noise and a verdict."""
    ys = [s[name][metric] for s in samples if metric in s.get(name, {})]
    if len(ys) < 5:
        return {"ok": None, "why": f"only {len(ys)} samples"}
    body = ys[max(1, len(ys) // 10) :]
    k = max(1, len(body) // 5)
    first, last = statistics.median(body[:k]), statistics.median(body[-k:])
    # within-window spread: a trend between the windows must not count as noise
    noise = max(statistics.pstdev(body[:k]), statistics.pstdev(body[-k:]))
    g = last - first
    floor = max(GROWTH_FLOOR[metric], 3 * noise, 0.02 * first if metric == "rss_mb" else 0.0)
    return {
        "start": round(first, 2),
        "end": round(last, 2),
        "growth": round(g, 2),
        "allowed": round(floor, 2),
        "ok": g <= floor,
    }


def refused_viewpoints(res: Any) -> tuple[int, list[str]]:
    """Viewpoints of a CycleResult the arm refused (not re-looks), and why; `cellctl demo` counts with it too.

    A refused viewpoint is one the scan could not reach at its planned joints, by IK nor at a
    nearby pose: its ``error`` is set. A whole-bin cycle also reports per station (``refused``
    per surface); the larger of the two counts is taken (a station's count includes views whose
    record was not kept)."""
    views = [v for v in res.viewpoints if v.error is not None and v.relook_of is None]
    by_station = sum(sum(st.refused.values()) for st in res.stations or [])
    why = [f"viewpoint {v.index} (station {v.station}, {v.surface}): {v.error}" for v in views]
    return max(len(views), by_station), why


def _plot(samples: list[dict[str, Any]], names: list[str], path: Path) -> Path | None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for metric, ax in zip(("rss_mb", "fds", "threads"), axes, strict=True):
        for name in names:
            pts = [(s["cycle"], s[name][metric]) for s in samples if metric in s.get(name, {})]
            if pts:
                ax.plot(*zip(*pts, strict=True), label=name)
        ax.set_xlabel("cycle")
        ax.set_ylabel({"rss_mb": "resident memory (MiB)", "fds": "open file descriptors", "threads": "threads"}[metric])
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"cellctl soak: {samples[-1]['cycle']} cycles")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def bench_soak(opts: BenchOptions) -> dict[str, Any]:
    """Run ``opts.n`` cycles (default 50) back to back and report throughput and resource curves."""
    import os

    from cellctl.bench.reliability.sim_cell import FAST_SIM, running_sim_cell
    from cellctl.errors import CellError

    n = opts.n or 50
    every = max(1, n // 100)
    outcomes: dict[str, int] = {}
    failures: list[str] = []
    refused: list[int] = []  # per cycle: viewpoints the arm refused (issue 19's target: 0)
    refusals: list[str] = []
    planned: list[int] = []
    with running_sim_cell(opts, "soak", FAST_SIM) as run:
        plc, cfg, out = run.plc, run.cfg, run.out
        roles = list(cfg.supervisor.spawn_workers)
        pids = {"daemon": os.getpid(), **{r: p.pid for r, p in run.cell.workers.procs.items()}}
        sampler = ResourceSampler(pids)
        t0 = time.monotonic()
        sampler.sample(0, 0.0)
        for i in range(1, n + 1):
            try:
                plc.to_idle()
                res = plc.run_cycle(600)
                outcome = res.outcome.value
                if outcome != "completed":
                    failures.append(f"cycle {i} {res.cycle_id}: {outcome}: {res.reason}")
                n_ref, why = refused_viewpoints(res)
                refused.append(n_ref)
                refusals += [f"cycle {i}: {w}" for w in why]
                planned.append(sum(sum(st.viewpoints.values()) for st in res.stations or []) or len(res.viewpoints))
            except CellError as err:
                outcome = "error"
                failures.append(f"cycle {i}: {err}")
            outcomes[outcome] = outcomes.get(outcome, 0) + 1
            if i % every == 0 or i == n:
                row = sampler.sample(i, time.monotonic() - t0)
                rate = i / (time.monotonic() - t0) * 3600
                print(
                    f"soak {i}/{n}: {rate:.0f} cycles/h, daemon {row['daemon'].get('rss_mb')} MiB, "
                    f"{row['daemon'].get('fds')} fds, {row['daemon'].get('threads')} threads",
                    file=sys.stderr,
                )
        elapsed = time.monotonic() - t0
    names = ["daemon", *roles]
    verdict = {name: {m: growth(sampler.samples, name, m) for m in ("rss_mb", "fds", "threads")} for name in names}
    png = _plot(sampler.samples, names, out / "soak.png")
    from cellctl.recording.audit import verify_audit

    audit = verify_audit(cfg.path(cfg.recording.index), cfg.path(cfg.recording.dir))
    return {
        "cycles": n,
        "outcomes": outcomes,
        "failures": failures[:20],
        "elapsed_s": round(elapsed, 1),
        "cycles_per_hour": round(n / elapsed * 3600, 1),
        "config": dict(o.split("=", 1) for o in [*FAST_SIM, *opts.overrides]),
        "refused_viewpoints": sum(refused),
        "refused_by_cycle": refused,
        "planned_viewpoints_by_cycle": planned,
        "refusals": refusals[:20],
        "growth": verdict,
        "no_growth": all(v["ok"] is not False for per in verdict.values() for v in per.values()),
        "samples": sampler.samples,
        "plot": str(png) if png else None,
        "audit": audit.as_dict(),
        "out": str(out),
        "load_average": [round(x, 2) for x in os.getloadavg()],
    }
