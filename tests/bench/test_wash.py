"""bench wash's washable set: only the clumps whose dirty faces all lie on reachable faces."""

from __future__ import annotations

import numpy as np

from cellctl.bench.wash import washable_only
from cellctl.config import load_config
from cellctl.geometry.catalog import load_catalog, read_bin_mesh
from cellctl.sim.ground_truth import PowderField


def test_washable_only_keeps_the_clumps_on_reachable_faces_and_drops_the_rest() -> None:
    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    mesh = read_bin_mesh(cat.mesh_path("tote"))
    field = PowderField.sample(mesh, 0.8, 5)
    reach = mesh.centroids[:, 0] < 0.0  # "a nozzle reaches" the half of the bin at x < 0
    only = washable_only(field, mesh, reach)
    dirty = only.dirty_faces(mesh)
    assert dirty.any() and not (dirty & ~reach).any()
    assert 0 < len(only.radii) < len(field.radii)
    # a clump well inside the reachable half stays
    inside = (field.centres[:, 0] < -3 * field.radii) & (
        np.abs(field.centres[:, 0]) < np.abs(mesh.vertices[:, 0]).max() - 3 * field.radii
    )
    kept = {tuple(c) for c in only.centres}
    assert any(tuple(c) in kept for c in field.centres[inside])
