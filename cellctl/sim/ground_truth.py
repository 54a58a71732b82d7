"""Sim-only ground truth: the true bin pose and the true powder contamination.

Nothing outside the sim and the measurement code (benches, tests, dataset labels) may use
this module: the cell itself only knows what it measures.

Powder model: ``n = round(4 + 60 * amount)`` clumps, centred at area-weighted random points
of the bin surface (internal faces facing up are 3× as likely: powder settles), each with a
log-normal radius (median 3 cm, 1–8 cm) and a ragged edge (3-D value noise), plus loose
grains in a halo around each clump. A clump only covers faces of its own surface
(external/internal), so powder inside does not show through the 4 mm wall.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh, BinType
from cellctl.geometry.transforms import invert
from cellctl.surface import EXTERNAL, INTERNAL

__all__ = ["PowderField", "SprayPass", "true_T_base_bin", "value_noise3"]


def value_noise3(p: NDArray[np.float64], seed: int) -> NDArray[np.float64]:
    """Smooth 3-D value noise in [0, 1] at points (M, 3) (lattice spacing 1)."""
    p = np.asarray(p, dtype=np.float64)
    i0 = np.floor(p).astype(np.int64)
    f = p - i0
    f = f * f * (3 - 2 * f)

    def h(ix: NDArray[np.int64], iy: NDArray[np.int64], iz: NDArray[np.int64]) -> NDArray[np.float64]:
        v = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791) ^ (seed * 2654435761 + 1013904223)
        v = (v ^ (v >> 13)) * 1274126177
        v = v ^ (v >> 16)
        return (v & 0xFFFFFF).astype(np.float64) / float(0xFFFFFF)

    x, y, z = i0[:, 0], i0[:, 1], i0[:, 2]
    fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
    c000, c100, c010, c110 = h(x, y, z), h(x + 1, y, z), h(x, y + 1, z), h(x + 1, y + 1, z)
    c001, c101, c011, c111 = h(x, y, z + 1), h(x + 1, y, z + 1), h(x, y + 1, z + 1), h(x + 1, y + 1, z + 1)
    c00 = c000 + fx * (c100 - c000)
    c10 = c010 + fx * (c110 - c010)
    c01 = c001 + fx * (c101 - c001)
    c11 = c011 + fx * (c111 - c011)
    c0 = c00 + fy * (c10 - c00)
    c1 = c01 + fy * (c11 - c01)
    return c0 + fz * (c1 - c0)


@dataclass(frozen=True)
class SprayPass:
    """One pass of a washing jet over the bin (bin frame): where its spot ran on the surface.

    Attributes:
        spots: (K, 3) the jet's spot centres on the surface along the pass, in order, m.
        axes: (K, 3) the jet's unit direction at each spot.
        radius: footprint radius, m.
        cos_incidence: cosine of the largest jet-to-normal angle that still cleans.
        removal: fraction of the powder under the footprint the pass removes.
    """

    spots: NDArray[np.float64]
    axes: NDArray[np.float64]
    radius: float
    cos_incidence: float
    removal: float


@dataclass
class PowderField:
    """Powder clumps on a bin (bin frame) and the per-point powder opacity they give.

    Attributes:
        centres: (n, 3) clump centres on the surface (m, bin frame).
        radii: (n,) clump radii (m).
        surface: (n,) surface tag of each clump.
        normals: (n, 3) surface normal at each centre.
        washes: the spray passes run over the bin so far (:meth:`wash`); each leaves
            ``1 − removal`` of the powder under its footprint.
    """

    centres: NDArray[np.float64]
    radii: NDArray[np.float64]
    surface: NDArray[np.uint8]
    normals: NDArray[np.float64]
    seed: int
    washes: list[SprayPass] = field(default_factory=list)

    def wash(self, spray: SprayPass) -> None:
        """Run one spray pass: from now on the powder under its footprint is reduced by its removal."""
        self.washes.append(spray)

    def remaining(self, pts: NDArray[np.float64], normals: NDArray[np.float64] | None) -> NDArray[np.float64]:
        """(M,) fraction of the powder left at surface points after the passes run so far.

        A point is under a pass when it lies within the footprint radius of the jet's axis at
        some sample of the spot's path (sampled every radius/4) and its face meets the jet within
        the incidence limit (so the other side of a wall is not washed through it).
        """
        out = np.ones(len(pts))
        if not self.washes or len(pts) == 0:
            return out
        from scipy.spatial import cKDTree

        # every pass's spot path at once (one tree, one query: a re-inspection render after a
        # round of tens of passes stays well within a capture's time)
        S_l, A_l, P_l = [], [], []
        for k, sp in enumerate(self.washes):
            S, A = np.asarray(sp.spots, np.float64).reshape(-1, 3), np.asarray(sp.axes, np.float64).reshape(-1, 3)
            if len(S) > 1:  # densify the spot path so the footprint is continuous along it
                seg = np.linalg.norm(np.diff(S, axis=0), axis=1)
                n = np.maximum(1, np.ceil(seg / (sp.radius / 4)).astype(int))
                f = [np.arange(m) / m for m in n]
                S = np.concatenate([S[i] + (S[i + 1] - S[i]) * f[i][:, None] for i in range(len(n))] + [S[-1:]])
                A = np.concatenate([np.repeat(A[i : i + 1], n[i], 0) for i in range(len(n))] + [A[-1:]])
            S_l.append(S)
            A_l.append(A)
            P_l.append(np.full(len(S), k))
        S, A, P = np.concatenate(S_l), np.concatenate(A_l), np.concatenate(P_l)
        radius = np.array([sp.radius for sp in self.washes])
        cos_inc = np.array([sp.cos_incidence for sp in self.washes])
        removal = np.array([sp.removal for sp in self.washes])
        # the jet is a cylinder of the footprint's radius around its axis: on a face it meets
        # obliquely the footprint stretches by 1/cos(incidence), so search that far from the spot
        reach = radius / np.maximum(cos_inc, 0.2)
        hits = cKDTree(S).query_ball_point(pts, r=float(reach.max()))
        lens = np.fromiter((len(h) for h in hits), np.int64, len(hits))
        if lens.sum() == 0:
            return out
        pi = np.repeat(np.arange(len(pts)), lens)
        si = np.concatenate([np.asarray(h, np.int64) for h in hits if len(h)])
        k = P[si]
        v = pts[pi] - S[si]
        along = np.einsum("ij,ij->i", v, A[si])
        ok = np.linalg.norm(v, axis=1) <= reach[k]
        ok &= np.linalg.norm(v - along[:, None] * A[si], axis=1) <= radius[k]
        if normals is not None:
            ok &= -np.einsum("ij,ij->i", normals[pi], A[si]) >= cos_inc[k]
        # each pass counts once per point, however many of its spots cover it
        pairs = np.unique(pi[ok] * len(self.washes) + k[ok])
        with np.errstate(divide="ignore"):
            keep = np.log1p(-removal)  # removal 1 → -inf → nothing left
        acc = np.zeros(len(pts))
        np.add.at(acc, pairs // len(self.washes), keep[pairs % len(self.washes)])
        return np.exp(acc)

    @classmethod
    def sample(cls, mesh: BinMesh, amount: float, seed: int) -> PowderField:
        """Seeded clumps for ``amount`` in [0, 1] (0 = none)."""
        rng = np.random.default_rng([seed, 4242])
        n = 0 if amount <= 0 else int(round(4 + 60 * float(amount)))
        normals = mesh.normals
        w = mesh.areas * np.where((mesh.surface == INTERNAL) & (normals[:, 2] > 0.3), 3.0, 1.0)
        faces = rng.choice(mesh.n_faces, size=n, p=w / w.sum()) if n else np.zeros(0, dtype=np.int64)
        tri = mesh.vertices[mesh.faces[faces]]
        u, v = rng.uniform(size=(2, n))
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        centres = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
        radii = np.clip(rng.lognormal(np.log(0.03), 0.45, size=n), 0.01, 0.08)
        return cls(
            centres.reshape(-1, 3),
            radii,
            mesh.surface[faces].astype(np.uint8),
            normals[faces].reshape(-1, 3),
            int(seed),
        )

    def alpha(
        self,
        pts: NDArray[np.float64],
        surface: NDArray[np.integer],
        normals: NDArray[np.float64] | None = None,
    ) -> NDArray[np.float64]:
        """Powder opacity in [0, 1] at surface points (M, 3) of the given surface tags (M,)."""
        out = np.zeros(len(pts))
        if len(self.radii) == 0 or len(pts) == 0:
            return out
        from scipy.spatial import cKDTree

        reach = float(self.radii.max() * 1.8)
        for tag in (EXTERNAL, INTERNAL):
            mine = np.flatnonzero(self.surface == tag)
            sel = np.flatnonzero(surface == tag)
            if len(sel) == 0 or len(mine) == 0:
                continue
            tree = cKDTree(self.centres[mine])
            # only points near some clump get the (costly) noise and k-nearest evaluation
            d1, _ = tree.query(pts[sel], k=1, distance_upper_bound=reach)
            sel = sel[np.isfinite(d1)]
            if len(sel) == 0:
                continue
            ragged = value_noise3(pts[sel] / 0.012, self.seed)  # clump edge wobble, ~1 cm features
            grain = value_noise3(pts[sel] / 0.0015, self.seed + 17)  # ~1.5 mm grains
            k = min(4, len(mine))
            d, j = tree.query(pts[sel], k=k, distance_upper_bound=reach)
            if k == 1:
                d, j = d[:, None], j[:, None]
            valid = np.isfinite(d)
            jj = np.where(valid, j, 0)
            r = self.radii[mine][jj]
            if normals is not None:  # do not wrap around sharp edges onto other faces
                agree = np.einsum("mkj,mj->mk", self.normals[mine][jj], normals[sel]) > 0.2
                valid &= agree
            edge = r * (0.7 + 0.6 * ragged[:, None])
            core = np.clip((edge - d) / 0.006, 0, 1)
            halo = ((d < 1.6 * r) & (grain[:, None] > 0.80 + 0.15 * np.clip(d / r - 1, 0, 1))).astype(float)
            out[sel] = np.where(valid, np.maximum(core, 0.85 * halo), 0.0).max(axis=1)
        if self.washes:
            # only where there is powder: a render's hits are mostly clean steel
            has = np.flatnonzero(out > 0)
            out[has] *= self.remaining(pts[has], None if normals is None else normals[has])
        return out

    def dirty_faces(self, mesh: BinMesh, threshold: float = 0.5) -> NDArray[np.bool_]:
        """Faces (F,) whose centroid or a vertex has powder opacity above ``threshold`` (after the washes)."""
        tri = mesh.vertices[mesh.faces]
        pts = np.concatenate([tri.mean(axis=1), tri[:, 0], tri[:, 1], tri[:, 2]])
        tags = np.tile(mesh.surface, 4)
        nrm = np.tile(mesh.normals, (4, 1))
        a = self.alpha(pts, tags, nrm).reshape(4, -1)
        return (a > threshold).any(axis=0)


def true_T_base_bin(T_world_base: NDArray[np.float64], T_world_bin: NDArray[np.float64]) -> NDArray[np.float64]:
    """The true bin pose in the robot base frame."""
    return invert(T_world_base) @ T_world_bin


def powder_for(bin_type: BinType, mesh: BinMesh, dirty: bool, amount: float, seed: int) -> PowderField:
    """The scenario's powder field (empty when clean)."""
    return PowderField.sample(mesh, amount if dirty else 0.0, seed)
