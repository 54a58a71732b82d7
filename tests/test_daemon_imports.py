"""The daemon must not import torch, open3d, pybullet or OMPL: heavy libraries live in workers."""

from __future__ import annotations

import subprocess
import sys


def test_daemon_import_graph_is_light() -> None:
    code = (
        "import sys\n"
        "from cellctl.app import build_cell, load_identification\n"
        "from cellctl.config import load_config\n"
        "cfg = load_config()\n"
        "load_identification(cfg)\n"
        "import cellctl.cli, cellctl.cli.daemon, cellctl.supervisor.supervisor, cellctl.recording.replay\n"
        "heavy = [m for m in ('torch', 'open3d', 'pybullet', 'ompl', 'embreex') if m in sys.modules]\n"
        "print(','.join(heavy))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"the daemon imported {out.stdout.strip()}"
