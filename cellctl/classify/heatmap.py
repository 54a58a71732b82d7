"""Heat maps: compact wire form, a viewable image, projection onto mesh faces, fusion, re-look poses.

Light (numpy + OpenCV, embreex inside functions, no torch): the supervisor imports it.

* :func:`encode_heat` / :func:`decode_heat` — a per-patch dirt-probability map as base64 of
  uint8 (p × 255), row-major; 16×16 = 344 characters.
* :func:`heat_png` — the map colour-coded (``COLORMAP_INFERNO``) at the camera's aspect, for the
  cycle MCAP (a Foxglove ``CompressedImage``).
* :func:`footprint` / :func:`patch_evidence` — projection ``patches`` (the default of
  ``classifier.verdict.projection``): a face-index render of the view (:class:`MeshCaster`,
  Embree: the bin mesh and the ID board) casts rays through every patch of the map; each ray
  carries the heat at it onto the barycentric cell of the face it hits, so a patch's heat lands
  where its pixels are. Patches on (or next to) the board give nothing.
* :func:`project_heat` — projection ``samples``: face sample points (centroid and three points
  half-way to the corners) projected with the camera pose and pinhole intrinsics into the image,
  which the detector squashed to its square grid; bilinear lookup, the largest of the samples.
* :class:`FaceFusion` — fuses views per face in log-odds: the detector's patch probabilities
  are fitted on class-balanced patches, so ``logit(p)`` is a likelihood ratio, and independent
  views add; a face prior turns the sum back into a probability. Each view's ratio is clipped
  (±:data:`MAX_VIEW_LOGIT`) so one glaring view cannot settle a face alone.
* :func:`fuse_views` → :class:`FaceMap` (its ``as_json`` is the CycleResult's ``dirt_map`` with
  ``face_p``, one byte per face; :func:`fuse_config` takes the settings from a
  ``VerdictConfig``) and :func:`verdict` (the configurable bin rule).
* :func:`relook_pose` — a nearby camera pose that keeps the same surface point in view: the
  camera swings by a glance angle about a point ``depth`` ahead of it and shifts sideways.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ClassifierError

__all__ = [
    "MAX_VIEW_LOGIT",
    "UNSEEN_CODE",
    "FaceFusion",
    "FaceMap",
    "Footprint",
    "MeshCaster",
    "ViewEvidence",
    "board_quad",
    "decode_heat",
    "encode_heat",
    "face_probabilities",
    "footprint",
    "fuse_config",
    "fuse_views",
    "heat_png",
    "patch_evidence",
    "project_heat",
    "relook_pose",
    "verdict",
]

MAX_VIEW_LOGIT = 4.0
"""Largest log-likelihood ratio one view may add to a face (p 0.018–0.982)."""


def encode_heat(heat: NDArray[np.floating]) -> str:
    """``(G, G)`` probabilities → base64 of uint8 ``round(p·255)``."""
    q = np.clip(np.round(np.asarray(heat, np.float64) * 255.0), 0, 255).astype(np.uint8)
    return base64.b64encode(q.tobytes()).decode("ascii")


def decode_heat(text: str, grid: int) -> NDArray[np.float32]:
    """Inverse of :func:`encode_heat`.

    Raises:
        ClassifierError: not base64, or not ``grid``² values.
    """
    try:
        raw = base64.b64decode(text.encode("ascii"), validate=True)
    except (ValueError, UnicodeEncodeError) as err:
        raise ClassifierError(f"heat map is not base64: {err}") from err
    if len(raw) != grid * grid:
        raise ClassifierError(f"heat map has {len(raw)} values, expected {grid}x{grid} = {grid * grid}")
    return np.frombuffer(raw, np.uint8).reshape(grid, grid).astype(np.float32) / 255.0


def heat_png(heat: NDArray[np.floating], width: int = 256, height: int = 144) -> bytes:
    """The heat map as a colour PNG (inferno: black clean → yellow dirty) at ``width``×``height``."""
    q = np.clip(np.asarray(heat, np.float32) * 255.0, 0, 255).astype(np.uint8)
    big = cv2.resize(q, (width, height), interpolation=cv2.INTER_NEAREST)
    ok, buf = cv2.imencode(".png", cv2.applyColorMap(big, cv2.COLORMAP_INFERNO))
    if not ok:
        raise ClassifierError("heat map PNG encoding failed")
    return buf.tobytes()


def _samples(mesh: Any, faces: NDArray[np.int64], subdiv: int = 0) -> NDArray[np.float64]:
    """Points of each face: ``subdiv`` 0 = centroid and three points half-way to the corners;
    ``subdiv`` k ≥ 1 = the barycentric grid of step 1/k (corners and edges included:
    (k+1)(k+2)/2 points), so a spot anywhere on a large face lands on a sample."""
    tri = mesh.vertices[mesh.faces[faces]]  # (F, 3, 3)
    c = tri.mean(axis=1)
    if subdiv <= 0:
        return np.stack([c, *(0.5 * (c + tri[:, k]) for k in range(3))], axis=1)  # (F, 4, 3)
    w = np.array([(i, j, subdiv - i - j) for i in range(subdiv + 1) for j in range(subdiv + 1 - i)], np.float64)
    return np.einsum("sk,fkd->fsd", w / subdiv, tri)


def project_heat(
    heat: NDArray[np.floating],
    T_bin_cam: NDArray[np.float64],
    intrinsics: Any,
    mesh: Any,
    faces: NDArray[np.int64] | list[int],
    subdiv: int = 0,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Probability per visible face from one view's heat map.

    Args:
        heat: ``(G, G)`` per-patch dirt probability of the whole (squashed) image.
        T_bin_cam: camera optical frame (+Z forward, +Y down) in the bin frame (4, 4).
        intrinsics: ``fx, fy, cx, cy, width, height`` attributes (px).
        mesh: the bin mesh (bin frame).
        faces: faces the view sees (the plan's visibility; occlusion already handled there).

    Returns:
        ``(face ids, p)`` for the faces whose samples land in the image.
    """
    faces = np.asarray(faces, np.int64)
    faces = faces[(faces >= 0) & (faces < mesh.n_faces)]
    if len(faces) == 0:
        return faces, np.zeros(0)
    g = heat.shape[0]
    per = _samples(mesh, faces, subdiv)
    ns = per.shape[1]
    pts = per.reshape(-1, 3)
    T_cam_bin = np.linalg.inv(np.asarray(T_bin_cam, np.float64))
    pc = pts @ T_cam_bin[:3, :3].T + T_cam_bin[:3, 3]
    z = pc[:, 2]
    ok = z > 1e-3
    u = intrinsics.fx * pc[:, 0] / np.where(ok, z, 1.0) + intrinsics.cx
    v = intrinsics.fy * pc[:, 1] / np.where(ok, z, 1.0) + intrinsics.cy
    ok &= (u >= 0) & (u < intrinsics.width) & (v >= 0) & (v < intrinsics.height)
    gx = np.clip(u / intrinsics.width * g - 0.5, 0, g - 1)
    gy = np.clip(v / intrinsics.height * g - 0.5, 0, g - 1)
    x0, y0 = np.floor(gx).astype(int), np.floor(gy).astype(int)
    x1, y1 = np.minimum(x0 + 1, g - 1), np.minimum(y0 + 1, g - 1)
    fx, fy = gx - x0, gy - y0
    h = np.asarray(heat, np.float64)
    val = (h[y0, x0] * (1 - fx) + h[y0, x1] * fx) * (1 - fy) + (h[y1, x0] * (1 - fx) + h[y1, x1] * fx) * fy
    val = np.where(ok, val, -1.0).reshape(len(faces), ns)
    seen = (val >= 0).any(axis=1)
    return faces[seen], val[seen].max(axis=1)


# --- patch → face projection (a face-index render of the view) -----------------------------------

PATCH_SUB = 5
"""Rays per heat-map patch side (5 × 5 = 25 a patch, 6400 for a 16×16 map; ~2 ms a view). Odd, so
one ray goes through each patch centre, where the bilinear map has the patch's own value: a lone
hot patch (a small spot) keeps its full probability on the face under its centre."""

BOARD_MARGIN_M = 0.03
"""The ID board is cast as an occluder this much larger than its pattern on every side: a patch
whose rays hit it (or its rim, which ``mask_board`` leaves unfilled) is no evidence about steel."""

BOARD_HALO_PATCHES = 1
"""Patches this close (in patches, 8-connected) to one that sees the board are dropped too: the
detector's heat spreads about one patch past a thing it calls dirty (bench figures, round 6)."""

OFF_BIN = -1
"""Face id of a ray that misses the bin (the cabin, the floor, the lit scene past the rim)."""
ON_BOARD = -2
"""Face id of a ray that hits the ID board (plus :data:`BOARD_MARGIN_M`)."""


class MeshCaster:
    """First-hit rays on the bin mesh (bin frame), optionally with the ID board as an occluder.

    Embree through embreex (the twin's renderer uses it too), built once per mesh and board.
    """

    def __init__(self, mesh: Any, board: NDArray[np.float64] | None = None) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        V = np.asarray(mesh.vertices, np.float64)
        F = np.asarray(mesh.faces, np.int64)
        self.n_faces = len(F)
        if board is not None:
            F = np.vstack([F, len(V) + np.array([[0, 1, 2], [0, 2, 3]])])
            V = np.vstack([V, np.asarray(board, np.float64).reshape(4, 3)])
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=V.astype(np.float32), indices=F.astype(np.int32))

    def cast(
        self, origin: NDArray[np.float64], dirs: NDArray[np.float64]
    ) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """Face id per ray (:data:`OFF_BIN`, :data:`ON_BOARD`) and the hit's barycentric ``(u, v)``
        (weights of the face's second and third corner)."""
        o = np.ascontiguousarray(np.broadcast_to(np.asarray(origin, np.float32), dirs.shape))
        res = self._scene.run(o, np.ascontiguousarray(dirs, dtype=np.float32), output=1)
        f = res["primID"].astype(np.int64)
        f = np.where(f >= self.n_faces, ON_BOARD, np.where(f < 0, OFF_BIN, f))
        return f, np.stack([res["u"], res["v"]], -1)


def board_quad(bin_type: Any, margin: float = BOARD_MARGIN_M) -> NDArray[np.float64]:
    """The ID board's corners (4, 3) in the bin frame, ``margin`` m larger on every side."""
    w, h = bin_type.board.size_m
    m = margin
    c = np.array([[-m, -m, 0, 1], [w + m, -m, 0, 1], [w + m, h + m, 0, 1], [-m, h + m, 0, 1]], np.float64)
    return (np.asarray(bin_type.T_bin_board(), np.float64) @ c.T)[:3].T


@dataclass(frozen=True)
class Footprint:
    """Where one view's heat-map patches land: ``sub``² rays per patch, row-major over the image.

    Attributes:
        sub: rays per patch side.
        cell: (R,) row-major patch index of each ray.
        face: (R,) face the ray hits first (:data:`OFF_BIN`, :data:`ON_BOARD`).
        bary: (R, 2) barycentric ``(u, v)`` of the hit on its face.
    """

    sub: int
    cell: NDArray[np.int64]
    face: NDArray[np.int64]
    bary: NDArray[np.float32]


def footprint(
    caster: MeshCaster, T_bin_cam: NDArray[np.float64], intrinsics: Any, grid: int, sub: int = PATCH_SUB
) -> Footprint:
    """A face-index render of the view at ``grid·sub`` rays a side: patch (i, j) of the squashed
    ``grid``² map spans pixels ``[j·W/G, (j+1)·W/G) × [i·H/G, (i+1)·H/G)`` of the frame."""
    W, H = float(intrinsics.width), float(intrinsics.height)
    t = (np.arange(grid * sub, dtype=np.float64) + 0.5) / (grid * sub)
    uu, vv = np.meshgrid(t * W - 0.5, t * H - 0.5)  # OpenCV: integer pixel coordinates are pixel centres
    d = np.stack([(uu - intrinsics.cx) / intrinsics.fx, (vv - intrinsics.cy) / intrinsics.fy, np.ones_like(uu)], -1)
    d = d.reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    T = np.asarray(T_bin_cam, np.float64)
    face, bary = caster.cast(T[:3, 3], d @ T[:3, :3].T)
    rc = np.arange(grid * sub) // sub
    cell = (rc[:, None] * grid + rc[None, :]).reshape(-1).astype(np.int64)
    return Footprint(sub, cell, face, bary)


def _bilinear_rays(heat: NDArray[np.floating], fp: Footprint, idx: NDArray[np.int64]) -> NDArray[np.float64]:
    """The heat map bilinearly interpolated (patch centres as nodes) at rays ``idx``."""
    g = heat.shape[0]
    n = g * fp.sub
    r, q = idx // n, idx % n
    gx = np.clip((q + 0.5) / fp.sub - 0.5, 0, g - 1)
    gy = np.clip((r + 0.5) / fp.sub - 0.5, 0, g - 1)
    x0, y0 = np.floor(gx).astype(int), np.floor(gy).astype(int)
    x1, y1 = np.minimum(x0 + 1, g - 1), np.minimum(y0 + 1, g - 1)
    fx, fy = gx - x0, gy - y0
    h = np.asarray(heat, np.float64)
    return (h[y0, x0] * (1 - fx) + h[y0, x1] * fx) * (1 - fy) + (h[y1, x0] * (1 - fx) + h[y1, x1] * fx) * fy


def patch_evidence(
    heat: NDArray[np.floating],
    fp: Footprint,
    faces: NDArray[np.int64] | list[int],
    n_faces: int,
    *,
    cells: int = 4,
    share_full: float = 0.25,
    max_view_logit: float = MAX_VIEW_LOGIT,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """One view's log-likelihood ratio per **face cell** (face·cells² + cell).

    Each face is split into ``cells``² cells on its barycentric grid; a ray of the footprint that
    hits one of ``faces`` (the plan's faces of the view) gives its cell the heat map at the ray,
    bilinear between patch centres, as a clipped logit; a cell hit by several rays takes the
    largest. Patches that touch the ID board (:data:`ON_BOARD`), and their neighbours
    (:data:`BOARD_HALO_PATCHES`), give nothing. Dirty evidence from a
    patch is scaled by the share of the patch's on-bin rays that hit the face, up to 1 at
    ``share_full`` (0: off): a hot patch on a corner that a thin face only grazes does not make
    that face dirty on its own.
    """
    g = heat.shape[0]
    allowed = np.zeros(n_faces, bool)
    fa = np.asarray(faces, np.int64)
    allowed[fa[(fa >= 0) & (fa < n_faces)]] = True
    board = (np.bincount(fp.cell, weights=fp.face == ON_BOARD, minlength=g * g) > 0).reshape(g, g)
    if board.any() and BOARD_HALO_PATCHES > 0:  # the detector's heat spreads about a patch past what it sees
        k = 2 * BOARD_HALO_PATCHES + 1
        board = cv2.dilate(board.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    board = board.reshape(-1)
    ok = (fp.face >= 0) & ~board[fp.cell]
    ok[ok] = allowed[fp.face[ok]]
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    f, c, uv = fp.face[idx], fp.cell[idx], fp.bary[idx]
    q = np.clip(_bilinear_rays(heat, fp, idx), 1e-6, 1 - 1e-6)
    z = np.clip(np.log(q / (1 - q)), -max_view_logit, max_view_logit)
    if share_full > 0:
        on_bin = np.bincount(fp.cell[fp.face >= 0], minlength=g * g)
        _, inv, cnt = np.unique(f * (g * g) + c, return_inverse=True, return_counts=True)
        share = cnt[inv] / on_bin[c]
        z = np.where(z > 0, z * np.minimum(1.0, share / share_full), z)
    i = np.minimum((uv[:, 0] * cells).astype(np.int64), cells - 1)
    j = np.minimum((uv[:, 1] * cells).astype(np.int64), cells - 1)
    keys, inv = np.unique(f * cells * cells + i * cells + j, return_inverse=True)
    e = np.full(len(keys), -np.inf)
    np.maximum.at(e, inv, z)
    return keys, e


@dataclass
class FaceFusion:
    """Per-face dirt evidence accumulated over views (log-odds, see module doc).

    Attributes:
        n_faces: faces of the mesh.
        prior: prior probability that a face is dirty.
    """

    n_faces: int
    prior: float = 0.1
    clean_weight: float = 1.0
    """Weight of a view's clean evidence (negative log-odds): a view that saw a face without
    resolving a small spot on it (far, grazing) must not cancel the view that did."""
    max_view_logit: float = MAX_VIEW_LOGIT
    llr: NDArray[np.float64] = field(init=False)
    views: NDArray[np.int32] = field(init=False)

    def __post_init__(self) -> None:
        if not 0.0 < self.prior < 1.0:
            raise ClassifierError(f"face prior {self.prior!r} must be in (0, 1)")
        if not 0.0 < self.clean_weight <= 1.0:
            raise ClassifierError(f"face fusion clean_weight {self.clean_weight!r} must be in (0, 1]")
        self.llr = np.zeros(self.n_faces)
        self.views = np.zeros(self.n_faces, np.int32)

    def add(self, faces: NDArray[np.int64], p: NDArray[np.float64]) -> None:
        """One view's probabilities for ``faces``."""
        q = np.clip(np.asarray(p, np.float64), 1e-6, 1 - 1e-6)
        z = np.clip(np.log(q / (1 - q)), -self.max_view_logit, self.max_view_logit)
        self.llr[faces] += np.where(z < 0, self.clean_weight * z, z)
        self.views[faces] += 1

    def probability(self) -> NDArray[np.float64]:
        """``(F,)`` fused dirt probability (the prior where no view saw a face)."""
        z = np.log(self.prior / (1 - self.prior)) + self.llr
        return 1.0 / (1.0 + np.exp(-z))

    def seen(self) -> NDArray[np.bool_]:
        return self.views > 0


def relook_pose(
    T_cam: NDArray[np.float64], k: int, offset_m: float, glance_deg: float, depth: float
) -> NDArray[np.float64]:
    """The ``k``-th re-look pose near camera pose ``T_cam`` (any frame; optical +Z forward).

    The camera swings by ``glance_deg`` about the point ``depth`` m ahead of it (about its own
    x axis for even ``k``, y for odd; the sign alternates every two), then shifts
    ``offset_m`` sideways along the swing direction: the same spot seen at another glance
    angle, where a highlight or shadow that made the view ambiguous has moved.
    """
    T = np.asarray(T_cam, np.float64)
    axis = T[:3, 0] if k % 2 == 0 else T[:3, 1]
    sign = 1.0 if (k // 2) % 2 == 0 else -1.0
    a = np.deg2rad(glance_deg) * sign
    ax = axis / np.linalg.norm(axis)
    K = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
    R = np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K
    pivot = T[:3, 3] + depth * T[:3, 2]
    out = np.eye(4)
    out[:3, :3] = R @ T[:3, :3]
    out[:3, 3] = pivot + R @ (T[:3, 3] - pivot)
    side = np.cross(ax, out[:3, 2])
    out[:3, 3] += sign * offset_m * side / max(np.linalg.norm(side), 1e-9)
    return out


UNSEEN_CODE = 255
"""``face_p`` byte of a face no view saw; seen faces carry ``round(p · 254)``."""


@dataclass(frozen=True)
class ViewEvidence:
    """What one classified view says about the faces it sees.

    Attributes:
        faces: the faces the plan says the view sees.
        T_bin_cam: where the camera actually was, in the bin frame (4, 4).
        heat: the detector's per-patch map, or None (a whole-image model): then every face of
            the view gets the view's ``p_dirty``, the old coarse dirt map.
        p_dirty: the view's image-level probability.
    """

    faces: NDArray[np.int64]
    T_bin_cam: NDArray[np.float64]
    heat: NDArray[np.float32] | None
    p_dirty: float


@dataclass(frozen=True)
class FaceMap:
    """Per-face result of a cycle: fused probability, seen, dirty (``p ≥ face_threshold``)."""

    p: NDArray[np.float64]
    seen: NDArray[np.bool_]
    dirty: NDArray[np.bool_]
    dirty_area_m2: float

    def as_json(self) -> dict[str, Any]:
        """The CycleResult's ``dirt_map``: face id lists (as before) + ``face_p`` (one byte per face)."""
        code = np.where(self.seen, np.round(np.clip(self.p, 0, 1) * 254), UNSEEN_CODE).astype(np.uint8)
        n = len(self.p)
        return {
            "faces_total": n,
            "seen_dirty": np.flatnonzero(self.dirty).tolist(),
            "seen_clean": np.flatnonzero(self.seen & ~self.dirty).tolist(),
            "unseen_count": int(n - self.seen.sum()),
            "dirty_area_m2": round(self.dirty_area_m2, 5),
            "face_p": {
                "encoding": "base64 uint8 per face: round(p*254), 255 unseen",
                "data": base64.b64encode(code.tobytes()).decode("ascii"),
            },
        }


def face_probabilities(dirt_map: dict[str, Any], n_faces: int) -> NDArray[np.float64] | None:
    """Decode ``dirt_map["face_p"]``: ``(F,)`` probabilities, NaN where unseen; None if absent.

    Raises:
        ClassifierError: present but malformed or of another mesh size.
    """
    fp = dirt_map.get("face_p") if isinstance(dirt_map, dict) else None
    if not fp:
        return None
    try:
        raw = np.frombuffer(base64.b64decode(str(fp["data"]).encode("ascii"), validate=True), np.uint8)
    except (KeyError, TypeError, ValueError) as err:
        raise ClassifierError(f"dirt map face_p is malformed: {err}") from err
    if len(raw) != n_faces:
        raise ClassifierError(f"dirt map face_p has {len(raw)} faces, the mesh {n_faces}")
    return np.where(raw == UNSEEN_CODE, np.nan, raw / 254.0)


def fuse_views(
    views: list[ViewEvidence],
    mesh: Any,
    intrinsics: Any,
    *,
    prior: float = 0.1,
    face_threshold: float = 0.5,
    clean_weight: float = 1.0,
    max_view_logit: float = MAX_VIEW_LOGIT,
    subdiv: int = 0,
    projection: str = "samples",
    caster: MeshCaster | None = None,
    cells: int = 4,
    share_full: float = 0.25,
) -> FaceMap:
    """All views of a cycle → per-face dirt probability and dirty faces (``p ≥ face_threshold``).

    ``projection``:

    * ``samples`` — each face's sample points looked up in the heat map (:func:`project_heat`),
      fused per face (:class:`FaceFusion`);
    * ``patches`` — a face-index render of every view (:func:`footprint`, ``caster`` = the mesh
      and, to drop the patches on it, the ID board) carries each patch's heat onto the face cells
      its rays hit (:func:`patch_evidence`); views add per face cell in log-odds as in
      :class:`FaceFusion`, and a face's probability is that of its dirtiest seen cell.

    Raises:
        ClassifierError: unknown projection.
    """
    if projection == "samples":
        fusion = FaceFusion(mesh.n_faces, prior, clean_weight, max_view_logit)
        for v in views:
            if v.heat is not None:
                faces, p = project_heat(v.heat, v.T_bin_cam, intrinsics, mesh, v.faces, subdiv)
            else:
                faces = np.asarray(v.faces, np.int64)
                faces = faces[(faces >= 0) & (faces < mesh.n_faces)]
                p = np.full(len(faces), float(v.p_dirty))
            fusion.add(faces, p)
        p = fusion.probability()
        seen = fusion.seen()
    elif projection == "patches":
        FaceFusion(1, prior, clean_weight, max_view_logit)  # the same argument checks
        caster = caster if caster is not None else MeshCaster(mesh)
        k2 = cells * cells
        llr = np.zeros(mesh.n_faces * k2)
        nv = np.zeros(mesh.n_faces * k2, np.int32)
        for v in views:
            if v.heat is not None:
                fp = footprint(caster, v.T_bin_cam, intrinsics, v.heat.shape[0])
                keys, z = patch_evidence(
                    v.heat, fp, v.faces, mesh.n_faces, cells=cells, share_full=share_full, max_view_logit=max_view_logit
                )
            else:  # a whole-image model: its probability on every cell of every face it sees
                faces = np.asarray(v.faces, np.int64)
                faces = faces[(faces >= 0) & (faces < mesh.n_faces)]
                keys = (faces[:, None] * k2 + np.arange(k2)[None, :]).reshape(-1)
                q = min(max(float(v.p_dirty), 1e-6), 1 - 1e-6)
                z = np.full(len(keys), float(np.clip(np.log(q / (1 - q)), -max_view_logit, max_view_logit)))
            llr[keys] += np.where(z < 0, clean_weight * z, z)
            nv[keys] += 1
        pc = 1.0 / (1.0 + np.exp(-(np.log(prior / (1 - prior)) + llr)))
        pc = np.where(nv > 0, pc, -1.0).reshape(mesh.n_faces, k2)
        seen = (nv.reshape(mesh.n_faces, k2) > 0).any(axis=1)
        p = np.where(seen, pc.max(axis=1), prior)
    else:
        raise ClassifierError(f"heat projection {projection!r} is unknown; expected 'patches' or 'samples'")
    dirty = seen & (p >= face_threshold)
    return FaceMap(p, seen, dirty, float(mesh.areas[dirty].sum()))


def fuse_config(views: list[ViewEvidence], mesh: Any, intrinsics: Any, vc: Any, bin_type: Any = None) -> FaceMap:
    """:func:`fuse_views` with the settings of ``vc`` (a :class:`~cellctl.config.VerdictConfig`);
    ``bin_type`` (its ID board) makes the board an occluder whose patches are dropped."""
    caster = None
    if vc.projection == "patches":
        board = board_quad(bin_type, vc.board_margin_m) if bin_type is not None else None
        caster = MeshCaster(mesh, board)
    return fuse_views(
        views,
        mesh,
        intrinsics,
        prior=vc.face_prior,
        face_threshold=vc.face_threshold,
        projection=vc.projection,
        caster=caster,
        cells=vc.face_cells,
        share_full=vc.patch_share,
    )


def verdict(face_map: FaceMap, view_labels: list[str], rule: str = "faces", min_dirty_area_cm2: float = 0.0) -> str:
    """The bin verdict.

    ``faces``: dirty when the dirty faces' area exceeds ``min_dirty_area_cm2`` (0: any dirty
    face). ``views``: dirty when any view is labelled dirty (the rule before per-face fusion).

    Raises:
        ClassifierError: unknown rule.
    """
    if rule == "views":
        return "dirty" if "dirty" in view_labels else "clean"
    if rule != "faces":
        raise ClassifierError(f"verdict rule {rule!r} is unknown; expected 'faces' or 'views'")
    area_cm2 = face_map.dirty_area_m2 * 1e4
    return "dirty" if face_map.dirty.any() and area_cm2 >= min_dirty_area_cm2 else "clean"
