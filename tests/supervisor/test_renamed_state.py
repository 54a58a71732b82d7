"""A cycle.yaml whose states are named otherwise than the steps they run works end to end.

Before the runner ran ``STEPS[state name]``: ``rescan: {step: scanning}`` passed the loader and
then failed mid-cycle with "internal error". Now the runner runs the step the state names.
"""

from __future__ import annotations

import time
from pathlib import Path

from cellctl.app import build_cell
from cellctl.bus.plc_client import PlcClient
from cellctl.config import CellConfig, project_root
from cellctl.geometry.catalog import load_catalog
from tests.fakes.workers import FakeCell, fake_identify


def _root_with_cycle(tmp_path: Path, cycle_yaml: str) -> Path:
    """A config root that is the project's, except for states/cycle.yaml."""
    root = tmp_path / "root"
    root.mkdir()
    for entry in project_root().iterdir():
        if entry.name != "states":
            (root / entry.name).symlink_to(entry)
    (root / "states").mkdir()
    (root / "states" / "packml.yaml").write_text((project_root() / "states" / "packml.yaml").read_text())
    (root / "states" / "cycle.yaml").write_text(cycle_yaml)
    return root


def test_renamed_states_run_the_steps_they_name(cfg: CellConfig, tmp_path: Path) -> None:
    text = (project_root() / "states" / "cycle.yaml").read_text()
    text = text.replace("  scanning:\n    step: scanning", "  rescan:\n    step: scanning").replace(
        "hit: scanning", "hit: rescan"
    )
    text = text.replace("  classifying:\n    step: classifying", "  judging:\n    step: classifying").replace(
        "succeeded: classifying", "succeeded: judging"
    )
    assert "rescan:" in text and "judging:" in text
    catalog = load_catalog(cfg.path(cfg.catalog))
    cfg.root = _root_with_cycle(tmp_path, text)
    cell = build_cell(cfg, identification=(fake_identify, catalog))
    try:
        assert set(cell.supervisor.cycle.states) >= {"rescan", "judging"}
        with FakeCell(cfg, dirty_viewpoints={0}) as fake, PlcClient(cfg, "t") as plc:
            time.sleep(0.2)
            plc.to_idle()
            res = plc.run_cycle(timeout=30)
        assert res.outcome == "completed", res.reason
        assert res.verdict == "dirty" and fake.calls.count("move") == 3
        assert {"rescan", "judging"} <= set(res.timing["steps_s"])  # timed under the state's own name
    finally:
        cell.close()
