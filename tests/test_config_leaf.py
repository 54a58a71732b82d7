"""The config is a leaf: cellctl.config imports no domain module, and every key it offers says what it is."""

from __future__ import annotations

import typing

import pytest

from cellctl.cli import main
from cellctl.config import BACKENDS, CellConfig, backend_reading, config_leaves, register_backend

from .test_import_graph import MODULES, _imports

# What the config package may build on: vocabulary and limits that import nothing of the domain themselves.
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


PACKAGE = sorted(m for m in MODULES if m == "cellctl.config" or m.startswith("cellctl.config."))


def test_config_imports_no_domain_module() -> None:
    """Function-level imports included: a domain model checking config fields is the composition root's job.

    Every module of the package counts: its modules import one another and the leaves, nothing else."""
    assert len(PACKAGE) > 5, PACKAGE  # the package's modules were found (cellctl/config/*.py)
    outside = {m: sorted(_imports(m) - LEAVES - set(PACKAGE)) for m in PACKAGE}
    assert not any(outside.values()), {m: o for m, o in outside.items() if o}
    used = set().union(*(_imports(m) for m in PACKAGE)) & LEAVES
    for leaf in used:
        assert not _imports(leaf) & set(PACKAGE), leaf


def test_schema_config_prints_a_description_for_every_leaf(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema", "--config"]) == 0
    lines = capsys.readouterr().out.splitlines()
    leaves = config_leaves()
    assert len(lines) == len(leaves) > 100
    undescribed = [line for line in lines if not line.partition("  # ")[2].strip()]
    assert not undescribed, undescribed
    printed = {line.partition(" = ")[0] for line in lines}
    assert {"camera.device", "robot.ur.faults.monitor_hz", "nozzle.lance_radius_m", "sim.seed"} <= printed


def test_each_backend_registers_the_fields_only_it_reads_and_its_section_inherits_them() -> None:
    sections = {name: f.annotation for name, f in CellConfig.model_fields.items()}
    assert set(BACKENDS) == {"robot", "camera", "base"}
    for section, backends in BACKENDS.items():
        model = sections[section]
        assert set(typing.get_args(model.model_fields["backend"].annotation)) == set(backends), section
        owned: list[str] = []
        for name, fields in backends.items():
            assert issubclass(model, fields), f"{model.__name__} does not inherit {section}.backend {name!r}"
            owned += list(fields.model_fields)
        assert len(owned) == len(set(owned)), f"{section}: a field registered by two backends: {owned}"
    assert backend_reading("camera", "device") == "opencv" and backend_reading("camera", "width") is None
    with pytest.raises(ValueError, match="registered twice"):
        register_backend("camera", "opencv")(BACKENDS["camera"]["opencv"])


def test_the_schema_names_the_backend_of_a_backend_field(capsys: pytest.CaptureFixture[str]) -> None:
    main(["schema", "--config"])
    lines = dict(line.split(" = ", 1) for line in capsys.readouterr().out.splitlines())
    assert lines["camera.device"].endswith("# opencv: device index or stream URL")
    assert "# ur: " in lines["robot.ur.faults.monitor_hz"] and "# manual: " in lines["base.confirm_timeout_s"]
