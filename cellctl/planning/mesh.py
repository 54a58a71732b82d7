"""Load and check a bin mesh for planning; tell its external from its internal surface.

The mesh type is :class:`cellctl.geometry.catalog.BinMesh` (the catalog's and the twin's);
this module adds what planning needs on top of the catalog reader: any trimesh-readable
file, vertex merging, zero-area faces dropped, watertightness, and surface tags inferred
when a mesh has none.

The bin frame (ARCHITECTURE §5): origin at the centre of the top opening, +Z up, metres.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import PlanningError
from cellctl.geometry.catalog import BinMesh
from cellctl.hashing import bytes_sha256, file_sha256
from cellctl.surface import EXTERNAL, INTERNAL

__all__ = ["infer_surface_tags", "load_bin_mesh", "load_catalog_mesh", "mesh_from_arrays"]

MAX_BIN_EXTENT_M = 5.0  # a washable pharmaceutical bin is ~0.5–2 m; more means wrong units
MIN_BIN_EXTENT_M = 0.05
MIN_FACE_AREA_M2 = 1e-10


def mesh_from_arrays(
    vertices: NDArray,
    faces: NDArray,
    *,
    name: str = "mesh",
    internal: NDArray[np.bool_] | None = None,
    sha256: str | None = None,
    require_watertight: bool = False,
) -> BinMesh:
    """Validate arrays and build a :class:`BinMesh`.

    Zero-area faces are dropped (they have no normal and cannot be seen); duplicate and
    unreferenced vertices are merged.

    Raises:
        PlanningError: empty or non-finite mesh, implausible size (mm units?), no faces
            left, or not watertight when ``require_watertight``.
    """
    import trimesh

    V = np.asarray(vertices, dtype=np.float64)
    Fc = np.asarray(faces, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 3:
        raise PlanningError(f"mesh {name!r}: vertices must be (V>=3, 3), got {V.shape}")
    if Fc.ndim != 2 or Fc.shape[1] != 3 or len(Fc) == 0:
        raise PlanningError(f"mesh {name!r}: faces must be (F>0, 3) triangles, got {Fc.shape}")
    if not np.all(np.isfinite(V)):
        raise PlanningError(f"mesh {name!r}: vertices contain NaN/inf")
    if Fc.min() < 0 or Fc.max() >= len(V):
        raise PlanningError(f"mesh {name!r}: face indices must lie in [0, {len(V) - 1}], got [{Fc.min()}, {Fc.max()}]")
    ext = V.max(axis=0) - V.min(axis=0)
    if ext.max() > MAX_BIN_EXTENT_M:
        raise PlanningError(
            f"mesh {name!r}: extent {np.round(ext, 3).tolist()} exceeds {MAX_BIN_EXTENT_M} m; "
            "expected metres (is the mesh in millimetres? scale it by 0.001)"
        )
    if ext.max() < MIN_BIN_EXTENT_M:
        raise PlanningError(
            f"mesh {name!r}: extent {np.round(ext, 5).tolist()} m is below {MIN_BIN_EXTENT_M} m; expected metres"
        )
    tm = trimesh.Trimesh(V, Fc, process=True, validate=False)
    areas = tm.area_faces
    keep = areas > MIN_FACE_AREA_M2
    if internal is not None:
        internal = np.asarray(internal, dtype=bool)
        if internal.shape != (len(Fc),):
            raise PlanningError(f"mesh {name!r}: {internal.shape} surface tags for {len(Fc)} faces")
        if len(tm.faces) != len(Fc):
            raise PlanningError(f"mesh {name!r}: merging vertices changed the face count; tags no longer match")
        internal = internal[keep]
    if not np.all(keep):
        tm.update_faces(keep)
        tm.remove_unreferenced_vertices()
    if len(tm.faces) == 0:
        raise PlanningError(f"mesh {name!r}: every face has zero area (degenerate mesh)")
    watertight = bool(tm.is_watertight)
    if require_watertight and not watertight:
        raise PlanningError(f"mesh {name!r} is not watertight: {len(tm.faces)} faces with open edges")
    if sha256 is None:
        sha256 = bytes_sha256(np.ascontiguousarray(tm.vertices).tobytes() + np.ascontiguousarray(tm.faces).tobytes())
    mesh = BinMesh(
        vertices=np.asarray(tm.vertices, dtype=np.float64),
        faces=np.asarray(tm.faces, dtype=np.int64),
        surface=np.full(len(tm.faces), EXTERNAL, dtype=np.uint8),
        name=name,
        sha256=sha256,
        watertight=watertight,
    )
    if internal is None:
        internal = infer_surface_tags(mesh)
    return dataclasses.replace(mesh, surface=np.where(internal, INTERNAL, EXTERNAL).astype(np.uint8))


def load_bin_mesh(path: str | Path, *, name: str | None = None, internal: NDArray[np.bool_] | None = None) -> BinMesh:
    """Load a mesh file (STL/OBJ/PLY/…) in metres, bin frame.

    Surface tags: ``internal`` if given, else a sidecar ``<file>.surface.npy`` (one tag per face,
    the catalog's convention; ``cellctl geometry generate`` writes one), else inferred
    (:func:`infer_surface_tags`).

    Raises:
        PlanningError: the file is missing, unreadable, not a single triangle mesh, or bad
            (see :func:`mesh_from_arrays`).
    """
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise PlanningError(f"mesh file {str(p)!r} does not exist")
    try:
        loaded = trimesh.load(p, force="mesh", process=False)
    except Exception as err:  # trimesh raises many types for bad files
        raise PlanningError(f"mesh file {str(p)!r} cannot be read: {type(err).__name__}: {err}") from err
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise PlanningError(f"mesh file {str(p)!r} holds no triangles")
    side = p.with_suffix(p.suffix + ".surface.npy")
    if internal is None and side.is_file():
        tags = np.load(side)
        if tags.shape != (len(loaded.faces),) or not np.isin(tags, (EXTERNAL, INTERNAL)).all():
            raise PlanningError(
                f"surface tags {str(side)!r}: shape {tags.shape}, values {sorted(set(np.unique(tags).tolist()))[:5]}; "
                f"expected ({len(loaded.faces)},) of {EXTERNAL} (external) / {INTERNAL} (internal)"
            )
        internal = tags == INTERNAL
    return mesh_from_arrays(
        loaded.vertices,
        loaded.faces,
        name=name or p.stem,
        internal=internal,
        sha256=file_sha256(p),
    )


def infer_surface_tags(mesh: BinMesh, probe_depth: float = 0.02) -> NDArray[np.bool_]:
    """Guess which faces are internal when the catalog gives no tags.

    A face is internal when it faces a probe point just below the top-opening origin
    (``n · (o − c) > 0``) and the segment from that point to the face centroid crosses no
    other face: exactly the faces a camera poking through the hole could see. Rims (normal
    ⟂ the probe direction) and the outside (facing away) stay external.
    """
    o = np.array([0.0, 0.0, -probe_depth])
    to_o = o - mesh.centroids
    dist = np.linalg.norm(to_o, axis=1)
    facing = np.einsum("ij,ij->i", mesh.normals, to_o) > 1e-9 * np.maximum(dist, 1e-9)
    cand = np.flatnonzero(facing & (dist > 1e-6))
    out = np.zeros(len(mesh.faces), dtype=bool)
    if len(cand) == 0:
        return out
    from cellctl.planning.raycast import RayCaster

    rc = RayCaster(mesh.vertices, mesh.faces)
    dirs = -to_o[cand] / dist[cand, None]
    origins = np.repeat(o[None], len(cand), axis=0)
    out[cand] = rc.first_hit_is(origins, dirs, cand, dist[cand])
    return out


def load_catalog_mesh(catalog_path: str | Path, bin_type: str) -> BinMesh:
    """The mesh of a catalog bin type with its surface tags and file sha256.

    Raises:
        PlanningError: unknown bin type, missing/altered mesh file, or a bad mesh.
    """
    from cellctl.errors import ConfigError
    from cellctl.geometry.catalog import load_catalog

    try:
        cat = load_catalog(catalog_path, verify_meshes=False)
        cm = cat.load_mesh(bin_type)
        sha = file_sha256(cat.mesh_path(bin_type))
    except ConfigError as err:
        raise PlanningError(f"cannot load bin type {bin_type!r}: {err}") from err
    return mesh_from_arrays(cm.vertices, cm.faces, name=bin_type, internal=cm.surface == INTERNAL, sha256=sha)
