"""One whole-bin plan as a bench row, and median / worst over seeds: shared by ``bench whole-bin``
on the catalog (:mod:`cellctl.bench.planning.plans`) and on the shape family
(:mod:`cellctl.bench.planning.family`), so neither imports the other's module for them."""

from __future__ import annotations

from typing import Any

__all__ = ["PROCESSES", "machine_info", "median_worst", "whole_row"]

PROCESSES = 1
"""Plans at a time: one, so that each plan's wall time is its own (a plan itself evaluates its
candidate stations on every core: :attr:`cellctl.planning.whole.WholeParams.workers`)."""


def machine_info() -> dict[str, Any]:
    """What a bench's planning times were measured on: cores, plans at a time, workers per plan, the load."""
    import os
    import platform

    from cellctl.planning.parallel import default_workers

    return {
        "cpus": os.cpu_count(),
        "processes": PROCESSES,
        "workers_per_plan": default_workers(),
        "load_avg_start": list(os.getloadavg()),
        "python": platform.python_version(),
    }


def whole_row(plan: Any, plan_load: float | None = None) -> dict[str, Any]:
    j = plan.to_json()
    return {
        "seed": j["seed"],
        "stations": len(plan.stations),
        "station_candidates": [s["candidate"] for s in j["stations"]],
        "surfaces": {
            k: {kk: v[kk] for kk in ("area_fraction", "bound_fraction", "viewpoints", "reason")}
            for k, v in j["surfaces"].items()
        },
        "viewpoints": sum(v.viewpoints for v in plan.surfaces.values()),
        "planning_s": plan.times_s["total"],
        "planning_cpu_s": plan.times_s["cpu"],
        "planning_cpu_workers_s": plan.times_s.get("cpu_workers", 0.0),
        "load_avg_1min": plan_load,
        "cycle_time_s": plan.cycle_time_s,
        "base_moves_s": plan.base_moves_s,
        "exact_cover": j["exact_cover"],
        "dropped_unconnected": j["dropped_unconnected"],
        "unverified_moves": plan.counts.get("unverified_moves", 0),
        "replaced_unconnected": plan.counts.get("replaced_unconnected", 0),
        "unconnected_directions": plan.counts.get("unconnected_directions", 0),
        "reason": plan.reason,
    }


def median_worst(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Median and worst over seeds: worst = lowest coverage, highest times and counts of losses."""
    import numpy as np

    def pair(vals: list[float], worst: str) -> dict[str, float]:
        a = np.asarray(vals, dtype=float)
        return {"median": float(np.median(a)), "worst": float(a.min() if worst == "min" else a.max())}

    proven = [r["exact_cover"] for r in rows if r["exact_cover"] and r["exact_cover"]["proven"]]
    out: dict[str, Any] = {
        "stations": pair([r["stations"] for r in rows], "max"),
        "viewpoints": pair([r["viewpoints"] for r in rows], "max"),
        "planning_s": pair([r["planning_s"] for r in rows], "max"),
        "planning_cpu_s": pair([r["planning_cpu_s"] for r in rows], "max"),
        "load_avg_1min": pair([r.get("load_avg_1min") or 0.0 for r in rows], "max"),
        "cycle_time_s": pair([r["cycle_time_s"] for r in rows], "max"),
        "dropped_unconnected": pair([r["dropped_unconnected"] for r in rows], "max"),
        "unverified_moves": pair([r["unverified_moves"] for r in rows], "max"),
        # only proven covers are a bound (a timed-out MILP's incumbent is not)
        "exact_cover_stations": pair([e["stations"] for e in proven], "max") if proven else None,
        "exact_cover_viewpoints": pair([e["viewpoints"] for e in proven], "max") if proven else None,
        "exact_cover_proven": sum(bool(r["exact_cover"] and r["exact_cover"]["proven"]) for r in rows),
    }
    for surf in rows[0]["surfaces"]:
        got = [r["surfaces"][surf] for r in rows if r["surfaces"][surf]["reason"] is None]
        if not got:
            out[surf] = {"reason": rows[0]["surfaces"][surf]["reason"]}
            continue
        out[surf] = {
            "area_fraction": pair([g["area_fraction"] for g in got], "min"),
            "bound_fraction": pair([g["bound_fraction"] for g in got], "min"),
            "viewpoints": pair([g["viewpoints"] for g in got], "max"),
        }
    return out
