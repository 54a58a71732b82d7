"""The config is a leaf: cellctl.config imports no domain module, and every key it offers says what it is."""

from __future__ import annotations

import pytest

from cellctl.cli import main
from cellctl.config import config_leaves

from .test_import_graph import _imports

# What config.py may build on: vocabulary and limits that import nothing of the domain themselves.
LEAVES = {
    "cellctl.bus",
    "cellctl.bus.endpoints",
    "cellctl.bus.keys",
    "cellctl.errors",
    "cellctl.images",
    "cellctl.review",
    "cellctl.review.config",
    "cellctl.strict_model",
    "cellctl.surface",
}


def test_config_imports_no_domain_module() -> None:
    """Function-level imports included: a domain model checking config fields is the composition root's job."""
    assert _imports("cellctl.config") <= LEAVES, sorted(_imports("cellctl.config") - LEAVES)
    for leaf in LEAVES & set(_imports("cellctl.config")):
        assert "cellctl.config" not in _imports(leaf), leaf


def test_schema_config_prints_a_description_for_every_leaf(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema", "--config"]) == 0
    lines = capsys.readouterr().out.splitlines()
    leaves = config_leaves()
    assert len(lines) == len(leaves) > 100
    undescribed = [line for line in lines if not line.partition("  # ")[2].strip()]
    assert not undescribed, undescribed
    printed = {line.partition(" = ")[0] for line in lines}
    assert {"camera.device", "robot.ur.faults.monitor_hz", "nozzle.lance_radius_m", "sim.seed"} <= printed
