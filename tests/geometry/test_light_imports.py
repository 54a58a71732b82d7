"""The supervisor may import the catalog and robot model: they must not pull in heavy libraries."""

from __future__ import annotations

import subprocess
import sys


def test_catalog_and_robot_model_import_light() -> None:
    code = (
        "import sys, cellctl.geometry.catalog, cellctl.geometry.robot_model, cellctl.geometry.boards\n"
        "from cellctl.geometry.catalog import load_catalog\n"
        "from cellctl.config import project_root\n"
        "c = load_catalog(project_root() / 'config' / 'bins.yaml')\n"
        "c.get('case_study').T_bin_board(); c.by_marker_id(20)\n"
        "heavy = ('torch', 'open3d', 'pybullet', 'ompl', 'trimesh', 'cv2', 'ur_analytic_ik', 'embreex')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
