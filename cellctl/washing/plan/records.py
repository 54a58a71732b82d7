"""Wash plan records: the parameters, a sweep, an unwashable piece, the plan; the planner's reach limits."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.surface import SURFACES
from cellctl.washing.nozzle import NozzleModel

__all__ = ["MAX_REACH_M", "MAX_SWEEP_STEP_RAD", "Sweep", "Unwashable", "WashParams", "WashPlan"]

MAX_SWEEP_STEP_RAD = 0.6  # joint jump between neighbouring waypoints that still counts as one sweep
MAX_REACH_M = 1.3


@dataclass(frozen=True)
class WashParams:
    """How to turn a dirt map into a wash plan.

    Attributes:
        threshold: face probability that is washed.
        margin_m: dilation of the dirty faces.
        n_roll: rolls about the jet tried by reachability (the jet is round: any roll sprays alike).
        residue_rolls: rolls of the second cover pass, which replans every station for only the
            target points the first pass left short of their passes (0: no second pass).
        cpu_budget_s: the plan's CPU ceiling (keeps a round's planning within its 10 s when much
            dirt is out of reach; 2 s below it for what is not predicted): a station after the
            first (first or residue pass) runs its reachability only when the CPU used so far plus
            its predicted cost (its filtered poses times rolls, at the CPU per pose and roll
            measured on this plan's stations) fits; the stations skipped are counted in
            ``counts["stations_over_budget"]`` / ``["residue_stations_over_budget"]`` and their dirt
            is left for the next round.
        margin: collision clearance, m.
        max_stations: most base poses one wash plan uses.
        seed: seeds the tour's ant colony.
        q_start: start configuration (None: the robot's home).
    """

    threshold: float = 0.5
    margin_m: float = 0.02
    n_roll: int = 4
    residue_rolls: int = 12
    cpu_budget_s: float = 8.0
    max_stations: int = 8
    margin: float = 0.005
    seed: int = 0
    q_start: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Sweep:
    """One continuous pass of the jet along a raster line.

    Attributes:
        region, surface: the target region it washes and its surface tag.
        T_bin_noz: (K, 4, 4) nozzle poses along the sweep, in the order they are run.
        q: (K, 6) joint configurations, rad.
        faces: target faces it sprays.
        passes: how many times it is run (back and forth).
        station: index of the base pose it is run from.
    """

    region: int
    surface: int
    T_bin_noz: NDArray[np.float64]
    q: NDArray[np.float64]
    faces: NDArray[np.int64]
    passes: int = 1
    station: int = 0

    @property
    def length_m(self) -> float:
        p = self.T_bin_noz[:, :3, 3]
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


@dataclass(frozen=True)
class Unwashable:
    """A piece of a target region no sweep sprays: its faces, area and why."""

    region: int
    surface: int
    faces: NDArray[np.int64]
    area_m2: float
    centroid: NDArray[np.float64]
    reason: str

    def describe(self) -> str:
        """The piece in words: its size, surface, centre (bin frame, mm) and first faces."""
        ids = ", ".join(str(int(f)) for f in self.faces[:5]) + (", …" if len(self.faces) > 5 else "")
        c = ", ".join(f"{v * 1e3:.0f}" for v in self.centroid)
        return f"{self.area_m2 * 1e4:.0f} cm² of the {SURFACES[self.surface]} surface at ({c}) mm, faces {ids}"


@dataclass
class WashPlan:
    """The ordered sweeps, what they cover and what they cannot.

    Attributes:
        sweeps: in execution order.
        transits_free: per sweep, whether the straight joint motion from the previous sweep's
            end (or the start) is collision-free; False ones go via the start configuration.
        dirty: (F,) the faces the dirt map calls dirty; targets: after dilation.
        covered: (F,) target faces some sweep sprays; washed: (F,) any face a sweep sprays.
        passes: (F,) sweeps spraying each face.
        unwashable: target pieces no sweep reaches.
        reason: set when there is nothing to do or nothing can be done (no motion then).
        source: where the dirty faces came from (``face_p``, ``seen_dirty``) or None.
        counts, times_s: what each step kept and spent (wall clock).
        cpu_s: the process CPU time the plan took (the wall clock counts other processes' load too).
    """

    sweeps: tuple[Sweep, ...]
    transits_free: tuple[bool, ...]
    dirty: NDArray[np.bool_]
    targets: NDArray[np.bool_]
    covered: NDArray[np.bool_]
    washed: NDArray[np.bool_]
    passes: NDArray[np.int64]
    unwashable: tuple[Unwashable, ...]
    required_passes: int
    stations: tuple[NDArray[np.float64], ...]
    q_start: NDArray[np.float64]
    reason: str | None = None
    source: str | None = None
    counts: dict[str, int] = field(default_factory=dict)
    times_s: dict[str, float] = field(default_factory=dict)
    cpu_s: float = 0.0

    @property
    def moves(self) -> bool:
        return bool(self.sweeps)

    def summary(self, mesh: BinMesh) -> dict[str, Any]:
        """JSON-ready totals (areas in m²)."""
        a = mesh.areas
        return {
            "reason": self.reason,
            "source": self.source,
            "sweeps": len(self.sweeps),
            "passes_run": int(sum(s.passes for s in self.sweeps)),
            "waypoints": int(sum(len(s.q) * s.passes for s in self.sweeps)),
            "sweep_length_m": round(sum(s.length_m * s.passes for s in self.sweeps), 3),
            "dirty_m2": round(float(a[self.dirty].sum()), 5),
            "target_m2": round(float(a[self.targets].sum()), 5),
            "covered_m2": round(float(a[self.covered].sum()), 5),
            "washed_m2": round(float(a[self.washed].sum()), 5),
            "full_passes_m2": round(float(a[self.targets & (self.passes >= self.required_passes)].sum()), 5),
            "unwashable": [
                {"region": u.region, "faces": len(u.faces), "area_m2": round(u.area_m2, 5), "reason": u.reason}
                for u in self.unwashable
            ],
            "transits_via_start": int(sum(not f for f in self.transits_free)),
            "stations_used": sorted({s.station for s in self.sweeps}),
            "counts": dict(self.counts),
            "times_s": {k: round(v, 3) for k, v in self.times_s.items()},
            "cpu_s": round(self.cpu_s, 3),
        }


def _empty(
    mesh: BinMesh,
    nozzle: NozzleModel,
    poses: list[NDArray[np.float64]],
    q0: NDArray[np.float64],
    reason: str,
    dirty: NDArray[np.bool_] | None = None,
    targets: NDArray[np.bool_] | None = None,
    source: str | None = None,
) -> WashPlan:
    z = np.zeros(mesh.n_faces, bool)
    return WashPlan(
        sweeps=(),
        transits_free=(),
        dirty=z if dirty is None else dirty,
        targets=z if targets is None else targets,
        covered=z.copy(),
        washed=z.copy(),
        passes=np.zeros(mesh.n_faces, np.int64),
        unwashable=(),
        required_passes=nozzle.required_passes,
        stations=tuple(poses),
        q_start=q0,
        reason=reason,
        source=source,
    )
