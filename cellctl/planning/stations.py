"""Stations: where the mobile base parks around the bin (issue 19 item 1).

A *station* is a base pose ``T_bin_base`` from which the arm inspects part of the bin. The
candidates lie on a ring around the bin's footprint: for each approach direction ``u`` (every
360/n degrees, the board side first) the base stands ``park_distance_m`` beyond the bin's
extent along ``u`` (the board included), its arm's +x axis facing the bin — the same rule as
the sim's nominal parking pose (:func:`cellctl.sim.scene.nominal_T_bin_base`), which is the
candidate of the board side. A candidate is refused, with its reason, when the mobile base box
would touch the bin or leave the cabin (walls from :class:`StationParams`), or when its side
is not allowed by the config.

Choosing stations (:func:`choose_stations`) is a set cover over (station, viewpoint) pairs:
fewest stations first (every extra station must add at least ``min_gain_pct`` % of the upper
bound of some surface), then the viewpoints. :func:`exact_station_cover` is the MILP bound
beside this heuristic: the fewest stations, then the fewest viewpoints, that see the same
faces (HiGHS, time-limited).

Light module: numpy (+ scipy for the MILP); no OMPL.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import PlanningError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import BinMesh, BinType
from cellctl.geometry.transforms import invert, transform_from_xyz_rpy

__all__ = [
    "Candidate",
    "StationCover",
    "StationParams",
    "base_move_s",
    "candidate_stations",
    "choose_stations",
    "exact_station_cover",
]


@dataclass(frozen=True)
class StationParams:
    """What shapes the station candidates and the choice among them.

    Attributes:
        candidates: approach directions tried around the bin (every 360/candidates deg).
        park_distance_m: base origin beyond the bin's extent along the approach direction
            (the sim's nominal parking distance, 0.75 m).
        max_stations: most stations a whole-bin plan may use.
        min_gain_pct: a further station is taken only if it adds at least this % of some
            surface's upper bound (fewest stations first).
        cabin_half_m: cabin half-extents in x, y (m) around the cabin centre.
        bin_in_cabin: the bin's footprint position x, y (m) and yaw (deg) in the cabin.
        wall_clearance_m: the mobile base box must stay this far from the walls and the bin.
        allowed_deg: approach directions allowed (deg in the bin frame, 0 = +x, -90 = the
            board side of the catalog bins), each with ±(180/candidates) deg; None: all.
        inner_candidates: directions of a second, inner ring (0: none), the board side first.
        inner_park_distance_m: the inner ring's base origin beyond the bin's extent: close
            enough for the upper arm to reach over the rim and the forearm to dip into a deep
            bin (from ``park_distance_m`` the elbow cannot get above the opening of a 0.6 m drum).
        base_speed_m_s, base_turn_deg_s, park_s: the mobile base's drive model between
            stations (straight segments around the ring, turn on the spot, docking time).
    """

    candidates: int = 8
    park_distance_m: float = 0.75
    max_stations: int = 4
    min_gain_pct: float = 2.0
    cabin_half_m: tuple[float, float] = (2.5, 2.5)
    bin_in_cabin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wall_clearance_m: float = 0.05
    allowed_deg: tuple[float, ...] | None = None
    base_speed_m_s: float = 0.5
    base_turn_deg_s: float = 45.0
    park_s: float = 3.0
    inner_candidates: int = 0
    inner_park_distance_m: float = 0.35

    @property
    def n_candidates(self) -> int:
        """All candidates, both rings."""
        return self.candidates + self.inner_candidates

    def check(self) -> None:
        """Raise PlanningError naming the first bad parameter."""
        if not 1 <= self.candidates <= 36:
            raise PlanningError(f"stations.candidates {self.candidates!r} must be in 1..36")
        if self.park_distance_m <= 0:
            raise PlanningError(f"stations.park_distance_m {self.park_distance_m!r} must be positive metres")
        if not 0 <= self.inner_candidates <= 36:
            raise PlanningError(f"stations.inner_candidates {self.inner_candidates!r} must be in 0..36")
        if self.inner_candidates and not 0 < self.inner_park_distance_m < self.park_distance_m:
            raise PlanningError(
                f"stations.inner_park_distance_m {self.inner_park_distance_m!r} must be positive and below "
                f"park_distance_m {self.park_distance_m!r} (the inner ring lies inside the outer one)"
            )
        if not 1 <= self.max_stations <= self.n_candidates:
            raise PlanningError(f"stations.max_stations {self.max_stations!r} must be in 1..{self.n_candidates}")
        if not 0 <= self.min_gain_pct < 100:
            raise PlanningError(f"stations.min_gain_pct {self.min_gain_pct!r} must be in [0, 100)")
        if min(self.cabin_half_m) <= 0:
            raise PlanningError(f"stations.cabin_half_m {list(self.cabin_half_m)} must be positive metres")
        for name in ("base_speed_m_s", "base_turn_deg_s"):
            if getattr(self, name) <= 0:
                raise PlanningError(f"stations.{name} {getattr(self, name)!r} must be positive")


@dataclass(frozen=True, eq=False)
class Candidate:
    """A candidate station.

    Attributes:
        index: rank around the bin (0 = the board side, then counter-clockwise); the inner
            ring's candidates follow the outer ring's (``candidates`` … ``n_candidates - 1``).
        angle_deg: approach direction in the bin frame (deg, 0 = +x).
        T_bin_base: (4, 4) robot base pose in the bin frame.
        reason: why the base cannot park here; None when it can.
        ring_xy: (2,) the base origin in the bin frame (m), for drive times and pictures.
        ring: 0 = the outer ring (``park_distance_m``), 1 = the inner one.
    """

    index: int
    angle_deg: float
    T_bin_base: NDArray[np.float64]
    reason: str | None
    ring_xy: NDArray[np.float64] = field(repr=False)
    ring: int = 0

    @property
    def name(self) -> str:
        return f"s{self.index}@{self.angle_deg:+.0f}deg" + ("/inner" if self.ring else "")


def _support(points: NDArray[np.float64], u: NDArray[np.float64]) -> float:
    return float((points @ u).max())


def _board_points(bin_type: BinType | None) -> NDArray[np.float64]:
    if bin_type is None:
        return np.zeros((0, 2))
    T = bin_type.T_bin_board()
    w, h = bin_type.board.size_m
    P = T[:3, :3] @ np.array([[0, 0, 0], [w, 0, 0], [0, h, 0], [w, h, 0]], dtype=float).T + T[:3, 3:4]
    return P[:2].T


def _board_angle(mesh: BinMesh, bin_type: BinType | None) -> float:
    """Approach direction (deg) of the side the board is on; -90 (bin −y) without a board."""
    if bin_type is None:
        return -90.0
    c = _board_points(bin_type).mean(axis=0)
    if float(np.linalg.norm(c)) < 1e-6:
        return -90.0
    return math.degrees(math.atan2(c[1], c[0]))


def _box_corners(T_bin_base: NDArray[np.float64]) -> NDArray[np.float64]:
    """(4, 2) footprint corners of the mobile base box in the bin frame."""
    centre, size = rm.MOBILE_BASE_BOX
    hx, hy = size[0] / 2, size[1] / 2
    local = np.array(
        [[centre[0] + sx * hx, centre[1] + sy * hy, 0.0, 1.0] for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    )
    return (T_bin_base @ local.T)[:2].T


def _box_clear_of(points: NDArray[np.float64], T_bin_base: NDArray[np.float64], clearance: float) -> bool:
    """True when no footprint point lies within the mobile base box grown by ``clearance``."""
    centre, size = rm.MOBILE_BASE_BOX
    local = (invert(T_bin_base) @ np.c_[points, np.zeros(len(points)), np.ones(len(points))].T)[:2].T
    lo = centre[:2] - size[:2] / 2 - clearance
    hi = centre[:2] + size[:2] / 2 + clearance
    inside = np.all((local >= lo) & (local <= hi), axis=1)
    return not bool(inside.any())


def candidate_stations(mesh: BinMesh, bin_type: BinType | None, sp: StationParams) -> list[Candidate]:
    """Base poses on a ring around the bin, the board side first; refused ones carry their reason.

    The base height is the sim's: the mobile base stands on the floor (the mesh's lowest point)
    and the arm is mounted :data:`~cellctl.geometry.robot_model.BASE_HEIGHT_M` above it.
    """
    sp.check()
    V = mesh.vertices
    z_floor = float(V[:, 2].min())
    # footprint = every vertex below the mobile base's top (the base box is 0.7 m high)
    low = V[V[:, 2] <= z_floor + rm.BASE_HEIGHT_M + 0.05][:, :2]
    foot = np.vstack([V[:, :2], _board_points(bin_type)])
    a0 = _board_angle(mesh, bin_type)
    cx, cy, cyaw = sp.bin_in_cabin
    T_cabin_bin = transform_from_xyz_rpy([cx, cy, 0.0], [0.0, 0.0, math.radians(cyaw)])
    half = np.asarray(sp.cabin_half_m, dtype=float)
    out: list[Candidate] = []
    rings = [(0, sp.candidates, sp.park_distance_m)]
    if sp.inner_candidates:
        rings.append((1, sp.inner_candidates, sp.inner_park_distance_m))
    for ring, n_dir, dist in rings:
        for k in range(n_dir):
            ang = (a0 + 360.0 * k / n_dir + 180.0) % 360.0 - 180.0
            u = np.array([math.cos(math.radians(ang)), math.sin(math.radians(ang))])
            r = _support(foot, u) + dist
            xy = r * u
            yaw = math.radians(ang) + math.pi  # the arm's +x axis faces the bin
            T = transform_from_xyz_rpy([xy[0], xy[1], z_floor + rm.BASE_HEIGHT_M], [0.0, 0.0, yaw])
            reason = None
            if sp.allowed_deg is not None and not any(
                abs((ang - a + 180.0) % 360.0 - 180.0) <= 180.0 / n_dir + 1e-9 for a in sp.allowed_deg
            ):
                reason = (
                    f"approach direction {ang:+.0f} deg is not among the allowed ones {list(sp.allowed_deg)} (config)"
                )
            elif not _box_clear_of(low if len(low) else foot, T, sp.wall_clearance_m):
                reason = f"the mobile base at {np.round(xy, 2).tolist()} m would touch the bin"
            else:
                corners = (T_cabin_bin @ np.c_[_box_corners(T), np.zeros(4), np.ones(4)].T)[:2].T
                over = np.abs(corners) - (half - sp.wall_clearance_m)
                if (over > 0).any():
                    reason = (
                        f"the mobile base at {np.round(xy, 2).tolist()} m (bin frame) would hit the cabin wall "
                        f"(cabin ±{half[0]:g} × ±{half[1]:g} m, {1000 * float(over.max()):.0f} mm beyond)"
                    )
            out.append(Candidate(index=len(out), angle_deg=ang, T_bin_base=T, reason=reason, ring_xy=xy, ring=ring))
    return out


# --- choosing stations ---------------------------------------------------------------------


def choose_stations(
    seen: list[dict[str, NDArray[np.bool_]]],
    areas: dict[str, NDArray[np.float64]],
    bounds: dict[str, float],
    sp: StationParams,
    best_per_size: list[tuple[int, ...]] | None = None,
) -> tuple[list[int], dict[str, float]]:
    """The fewest stations whose union sees (almost) what all of them see, on both surfaces.

    Args:
        seen: per candidate station (usable ones), per surface, (m_surface,) faces some
            connected viewpoint of that station properly sees.
        areas: per surface, (m_surface,) face areas, m².
        bounds: per surface, the upper bound's area (m²) that fractions are taken of.
        sp: station parameters (``max_stations``, ``min_gain_pct``).
        best_per_size: if given, filled with the best subset of every size tried (the one the
            gain rule refused included): what a caller choosing on estimates evaluates in full.

    Returns:
        ``(chosen station positions in ``seen``, score per subset size tried)``: exhaustive
        over subsets of each size (≤ C(8, 4) = 70), the next size only when it adds at least
        ``min_gain_pct`` % of some surface's bound.
    """
    n = len(seen)
    if n == 0:
        return [], {}
    surfaces = [s for s in areas if bounds.get(s, 0.0) > 0]

    def fractions(sub: tuple[int, ...]) -> NDArray[np.float64]:
        out = []
        for s in surfaces:
            m = np.zeros(len(areas[s]), dtype=bool)
            for i in sub:
                m |= seen[i][s]
            out.append(float(areas[s][m].sum()) / bounds[s])
        return np.array(out)

    best: tuple[int, ...] = ()
    best_f = np.zeros(len(surfaces))
    tried: dict[str, float] = {}
    for size in range(1, min(sp.max_stations, n) + 1):
        cand = max(itertools.combinations(range(n), size), key=lambda sub: (float(fractions(sub).sum()), -sum(sub)))
        f = fractions(cand)
        tried[str(size)] = float(f.sum())
        if best_per_size is not None:
            best_per_size.append(cand)
        if best and not (f - best_f > sp.min_gain_pct / 100.0).any():
            break
        best, best_f = cand, f
    return list(best), tried


@dataclass(frozen=True)
class StationCover:
    """The exact (station, viewpoint) cover: fewest stations, then fewest viewpoints, seeing the same faces."""

    stations: int | None
    viewpoints: int | None
    proven: bool
    seconds: float


def exact_station_cover(
    columns: list[tuple[int, NDArray[np.bool_]]], must: NDArray[np.bool_], time_limit_s: float = 10.0
) -> StationCover:
    """MILP over (station, viewpoint) pairs (scipy milp / HiGHS).

    min W·Σ y_s + Σ x_p  s.t. every face in ``must`` is seen by a chosen pair, x_p ≤ y_station(p);
    W = number of pairs + 1, so one station outweighs any number of viewpoints.

    Args:
        columns: per pair, (station id, (m,) faces it sees) over the faces of both surfaces.
        must: (m,) the faces to cover (what the heuristic's selection sees).
    """
    from scipy.optimize import Bounds, LinearConstraint, milp
    from scipy.sparse import csr_matrix, hstack

    t0 = time.perf_counter()
    if not must.any() or not columns:
        return StationCover(0, 0, True, 0.0)
    A_all = np.array([c for _, c in columns]).T[must]  # (m, pairs)
    if not A_all.any(axis=1).all():
        raise PlanningError("exact station cover: a face to cover is seen by no (station, viewpoint) pair")
    columns = _undominated(columns, A_all)
    st_ids = sorted({s for s, _ in columns})
    P, S = len(columns), len(st_ids)
    A = np.array([c for _, c in columns]).T[must]  # (m, P)
    A = np.unique(A, axis=0)
    cover = hstack([csr_matrix(A.astype(np.float64)), csr_matrix((A.shape[0], S))])
    link = np.zeros((P, P + S))
    for p, (s, _) in enumerate(columns):
        link[p, p] = 1.0
        link[p, P + st_ids.index(s)] = -1.0
    cons = [
        LinearConstraint(cover, lb=1.0, ub=np.inf),
        LinearConstraint(csr_matrix(link), lb=-np.inf, ub=0.0),
    ]
    c = np.r_[np.ones(P), np.full(S, float(P + 1))]
    res = milp(
        c=c,
        constraints=cons,
        integrality=np.ones(P + S),
        bounds=Bounds(0, 1),
        options={"time_limit": time_limit_s, "disp": False},
    )
    dt = time.perf_counter() - t0
    if res.x is None:
        return StationCover(None, None, False, dt)
    x = np.round(res.x)
    return StationCover(int(x[P:].sum()), int(x[:P].sum()), bool(res.status == 0), dt)


def _undominated(
    columns: list[tuple[int, NDArray[np.bool_]]], A: NDArray[np.bool_]
) -> list[tuple[int, NDArray[np.bool_]]]:
    """The pairs no other pair of the same station beats: it sees a face to cover, and no pair of
    its station sees a superset of those faces (ties: the first kept). Dropping the others keeps
    the optimum (a dominating pair costs the same and needs the same station) and shrinks the
    MILP several times, so HiGHS proves it within its time limit."""
    stations = np.array([s for s, _ in columns])
    keep = np.zeros(len(columns), dtype=bool)
    for s in np.unique(stations):
        idx = np.flatnonzero(stations == s)
        idx = idx[A[:, idx].any(axis=0)]
        if len(idx) == 0:
            continue
        B = A[:, idx].astype(np.float32)
        outside = B.T @ (1.0 - B)  # [i, j]: faces i sees that j does not
        sub = outside < 0.5  # i ⊆ j
        n = np.arange(len(idx))
        strict = sub & ~sub.T  # i ⊂ j strictly
        tie = sub & sub.T & (n[None, :] < n[:, None])  # an equal column earlier
        keep[idx[~(strict | tie).any(axis=1)]] = True
    return [c for c, k in zip(columns, keep, strict=True) if k]


def base_move_s(cands: list[Candidate], a: int, b: int, sp: StationParams) -> float:
    """Modelled drive time from candidate ``a`` to ``b``: around the ring (the shorter way), turn, dock.

    The base drives the straight segments between consecutive outer-ring positions (never
    across the bin), turns on the spot by the change of heading and docks (``park_s``). An
    inner-ring candidate is reached straight out from (and left straight back to) the outer
    ring position of the nearest direction: the drive between two close stations goes round
    the outside, where the base is known to clear the bin.
    """
    if a == b:
        return 0.0
    by_index = {c.index: c for c in cands}
    outer = sorted((c for c in cands if c.ring == 0), key=lambda c: c.index)
    n = len(outer)

    def dock(c: Candidate) -> tuple[int, float]:
        """(position on the outer ring, straight distance to it)."""
        if c.ring == 0:
            return outer.index(c), 0.0
        k = min(range(n), key=lambda i: abs((outer[i].angle_deg - c.angle_deg + 180.0) % 360.0 - 180.0))
        return k, float(np.linalg.norm(outer[k].ring_xy - c.ring_xy))

    (ka, da), (kb, db) = dock(by_index[a]), dock(by_index[b])
    best = math.inf
    for step in (1, -1):
        length, k = 0.0, ka
        while k != kb:
            nxt = (k + step) % n
            length += float(np.linalg.norm(outer[nxt].ring_xy - outer[k].ring_xy))
            k = nxt
        best = min(best, length)
    turn = abs((by_index[b].angle_deg - by_index[a].angle_deg + 180.0) % 360.0 - 180.0)
    return (best + da + db) / sp.base_speed_m_s + turn / sp.base_turn_deg_s + sp.park_s
