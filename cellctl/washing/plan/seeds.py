"""Wash seeds: raster waypoints per facet, the residue pass's extra candidates, the points demand is
counted on, and the nozzle poses per waypoint (with the lance's own clearance)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.surface import INTERNAL
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.targets import Facet

__all__ = ["OPENING_RISE_M", "RESIDUE_AZIMUTHS", "RESIDUE_TILTS_DEG"]

OPENING_RISE_M = 0.1  # internal jets radiate from this far above the opening's centre


@dataclass(frozen=True)
class _Line:
    facet: int
    points: NDArray[np.float64]  # (K, 3) surface points along the line, in sweep order
    faces: NDArray[np.int64]  # (K,) nearest facet face of each
    extra: bool = False  # a residue candidate tilted off its point's normal: no internal-rule jet of its own


def _raster(mesh: BinMesh, fc: Facet, k: int, spacing: float) -> list[_Line]:
    """Boustrophedon raster lines over one facet, lines ``spacing`` apart along its longer extent."""
    from scipy.spatial import cKDTree

    n = fc.normal
    c = mesh.centroids[fc.faces]
    o = (c * mesh.areas[fc.faces, None]).sum(0) / mesh.areas[fc.faces].sum()
    # the raster spans the facet's triangles, corners included, not only their centroids
    corners = mesh.vertices[mesh.faces[fc.faces]]  # (n, 3, 3)
    ext = np.concatenate([c, corners.reshape(-1, 3)])
    ext_face = np.concatenate([fc.faces, np.repeat(fc.faces, 3)])
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    uv = np.stack([(ext - o) @ e1, (ext - o) @ e2], axis=1)
    if len(fc.faces) > 2:  # sweep along the principal axis: fewer, longer lines
        w, V = np.linalg.eigh(np.cov(uv.T))
        a = V[:, int(np.argmax(w))]
        e1, e2 = a[0] * e1 + a[1] * e2, -a[1] * e1 + a[0] * e2
        uv = np.stack([(ext - o) @ e1, (ext - o) @ e2], axis=1)
    step = 0.7 * spacing  # a waypoint's spot (radius ≥ 0.71·spacing) then reaches half-way to the next line's
    tree = cKDTree(uv)
    lo, hi = uv.min(0), uv.max(0)
    reach = step  # a waypoint within a step of some point of the facet's triangles
    lines: list[_Line] = []
    n_rows = max(1, int(np.ceil((hi[1] - lo[1]) / spacing)))
    v0 = (lo[1] + hi[1]) / 2 - (n_rows - 1) * spacing / 2
    us = np.arange(lo[0], hi[0] + step * 0.5, step) if hi[0] > lo[0] else np.array([lo[0]])
    for r in range(n_rows):
        v = v0 + r * spacing
        q = np.stack([us, np.full(len(us), v)], axis=1)
        d, j = tree.query(q)
        ok = d <= reach
        if not ok.any():
            continue
        q, j = q[ok], j[ok]
        if r % 2:
            q, j = q[::-1], j[::-1]
        P = o + q[:, :1] * e1 + q[:, 1:] * e2
        P += ((ext[j] - P) @ n)[:, None] * n  # onto the plane of the nearest triangle point
        lines.append(_Line(k, P, ext_face[j]))
    return lines


RESIDUE_TILTS_DEG = (0.0, 30.0, 50.0)
"""Jet tilts off a residue point's normal the second cover pass tries (50°: inside the default 60° incidence limit)."""
RESIDUE_AZIMUTHS = 6


def _residue_lines(
    mesh: BinMesh, facets: list[Facet], fp: _FacePoints, need: NDArray[np.int64], targets: NDArray[np.bool_]
) -> tuple[list[Facet], list[_Line]]:
    """Extra candidates for the target points still short of passes: one single-waypoint line
    per point and jet direction, aimed at the point (a corner pulled a fifth of the way into a target
    face it belongs to, off the edge) along the mean normal of its target faces and that normal
    tilted by :data:`RESIDUE_TILTS_DEG` at :data:`RESIDUE_AZIMUTHS` azimuths: the first pass's
    jet follows a facet's mean normal, which a corner on a crease or a face deep inside a
    narrow opening needs at another angle."""
    region_of = np.full(mesh.n_faces, -1)
    for fc in facets:
        region_of[fc.faces] = fc.region
    out_f: list[Facet] = []
    out_l: list[_Line] = []
    fpts, pos = fp.ids, fp.pos
    tf = np.flatnonzero(targets)
    short = need[fpts[tf]] > 0  # (T, K)
    done: set[int] = set()
    for row, col in zip(*np.nonzero(short), strict=True):
        pid = int(fpts[tf[row], col])
        if pid in done:
            continue
        done.add(pid)
        owners = tf[(fpts[tf] == pid).any(axis=1)]
        f = int(owners[0])
        nm = (mesh.normals[owners] * mesh.areas[owners, None]).sum(axis=0)
        nm = nm / max(float(np.linalg.norm(nm)), 1e-12)
        pt = 0.8 * pos[f, col] + 0.2 * mesh.centroids[f] if 1 <= col <= 3 else pos[f, col]  # corners only
        helper = np.array([0.0, 0.0, 1.0]) if abs(nm[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(nm, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nm, e1)
        dirs = [nm]
        for tilt in RESIDUE_TILTS_DEG[1:]:
            t = np.deg2rad(tilt)
            for k in range(RESIDUE_AZIMUTHS):
                az = 2 * np.pi * k / RESIDUE_AZIMUTHS
                dirs.append(np.cos(t) * nm + np.sin(t) * (np.cos(az) * e1 + np.sin(az) * e2))
        for j, d in enumerate(dirs):
            out_l.append(_Line(len(out_f), pt[None], np.array([f], np.int64), extra=j > 0))
            out_f.append(Facet(int(region_of[f]), int(mesh.surface[f]), np.array([f], np.int64), d))
    return out_f, out_l


@dataclass(frozen=True)
class _FacePoints:
    """The points demand is counted on, per face (F, K): ids (a point shared by faces has one id),
    positions, and which slots are real (the rest repeat the face's centroid, to keep K per face)."""

    ids: NDArray[np.int64]
    pos: NDArray[np.float64]
    real: NDArray[np.bool_]


def _face_points(mesh: BinMesh, spacing: float) -> _FacePoints:
    """Each face's centroid (id = face id), its corners (welded by position), and inside a face some
    part of which lies further than ``spacing`` from all of those, more points (farthest first, until
    every part of it is within ``spacing`` of one; ids after the corners'). The plan passes the raster's
    line spacing: a face is then represented as densely as a sweep covers it.

    Why: the demo's dirty sliver (face 4365 of the case study, 58 cm long and 5 cm wide, where the
    jet along its normal cannot go) had its powder between its centroid and a corner, 6 cm from both:
    the residue pass aimed at those four points only, and the powder between stayed."""
    key = np.round(mesh.vertices / 1e-5).astype(np.int64)
    _, weld = np.unique(key, axis=0, return_inverse=True)
    ids = np.concatenate([np.arange(mesh.n_faces)[:, None], mesh.n_faces + weld.reshape(-1)[mesh.faces]], axis=1)
    tri = mesh.vertices[mesh.faces]
    pos = np.concatenate([mesh.centroids[:, None], tri], axis=1)
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    extra: dict[int, NDArray[np.float64]] = {}
    for f in np.flatnonzero(longest > 1.5 * spacing):  # (a shorter face is within spacing of its corners)
        m = int(np.ceil(2 * longest[f] / spacing))  # a barycentric grid half the spacing apart
        i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
        ok = i + j <= m
        b = np.stack([i[ok], j[ok], m - i[ok] - j[ok]], axis=1) / m
        cand = b @ tri[f]
        d = np.linalg.norm(cand[:, None] - pos[f][None], axis=2).min(axis=1)
        kept = []
        while d.max() > spacing:
            k = int(np.argmax(d))
            kept.append(cand[k])
            d = np.minimum(d, np.linalg.norm(cand - cand[k], axis=1))
        if kept:
            extra[int(f)] = np.array(kept)
    n_extra = max((len(v) for v in extra.values()), default=0)
    real = np.zeros((mesh.n_faces, 4 + n_extra), bool)
    real[:, :4] = True
    ids = np.concatenate([ids, np.repeat(ids[:, :1], n_extra, axis=1)], axis=1)
    pos = np.concatenate([pos, np.repeat(pos[:, :1], n_extra, axis=1)], axis=1)
    nxt = int(ids.max()) + 1
    for face, P in extra.items():  # not ``f``: above it is a numpy index, here a dict key (mypy)
        ids[face, 4 : 4 + len(P)] = np.arange(nxt, nxt + len(P))
        pos[face, 4 : 4 + len(P)] = P
        real[face, 4 : 4 + len(P)] = True
        nxt += len(P)
    return _FacePoints(ids, pos, real)


def _nozzle_poses(
    mesh: BinMesh,
    pts: NDArray[np.float64],
    nrm: NDArray[np.float64],
    faces: NDArray[np.int64],
    nozzle: NozzleModel,
    opening_rule: NDArray[np.bool_] | None = None,
) -> Any:
    """Candidate nozzle poses per waypoint, in preference order: the jet along −normal at each
    stand-off (the external viewpoint rule), then — inside the bin — the jet from the top
    opening's centre through the waypoint (the internal viewpoint rule) where that meets the
    face within the incidence limit."""
    from cellctl.planning.viewpoints import Viewpoints, generate_viewpoints

    d = nozzle.distances
    a = generate_viewpoints(pts, nrm, faces, "external", d)
    inside_ok = mesh.surface[faces] == INTERNAL
    if opening_rule is not None:
        inside_ok &= opening_rule
    inside = np.flatnonzero(inside_ok)
    if len(inside) == 0:
        return a
    top = (0.0, 0.0, float(mesh.vertices[:, 2].max()) + OPENING_RISE_M)
    b = generate_viewpoints(pts[inside], nrm[inside], faces[inside], "internal", d, origin=top)
    k = b.T[:, :3, 2]
    cos_inc = -np.einsum("ij,ij->i", k, nrm[inside][b.seed])
    ok = cos_inc >= np.cos(np.deg2rad(nozzle.max_incidence_deg)) - 1e-9
    ok &= cos_inc < 0.999  # where the two rules give the same jet, the first is enough
    b = b.subset(np.flatnonzero(ok))
    return Viewpoints(
        np.concatenate([a.T, b.T]),
        np.concatenate([a.seed, inside[b.seed]]),
        np.concatenate([a.rank, b.rank + len(d)]),
        np.concatenate([a.seed_face, b.seed_face]),
        np.concatenate([a.seed_point, b.seed_point]),
    )


def _lance_free(T_bin_noz: NDArray[np.float64], nozzle: NozzleModel, world: Any) -> NDArray[np.bool_]:
    """(N,) True where the lance (flange → tip) clears the bin and the floor."""
    if len(T_bin_noz) == 0:
        return np.zeros(0, bool)
    a, b = nozzle.lance_segment(T_bin_noz)
    f = np.linspace(0.0, 1.0, 5)
    P = (a[:, None] + (b - a)[:, None] * f[None, :, None]).reshape(-1, 3)
    thr = nozzle.lance_radius_m + world.margin
    grid = world.sim.grid
    hit = grid.interp(P) < thr
    if hit.any():
        idx = np.flatnonzero(hit)
        hit[idx] = grid.exact(P[idx]) < thr
    hit |= P[:, 2] - thr < world.floor_z
    return ~hit.reshape(len(T_bin_noz), -1).any(axis=1)
