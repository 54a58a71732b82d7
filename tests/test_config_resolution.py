"""Which config a command reads, and where its relative paths point (issue 32, item 2).

``--config``, else ``$CELLCTL_CONFIG``, else ``./config/cell.yaml`` in the working directory, else
the packaged defaults with the outputs under ``./logs``; every command says which on stderr.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.cli import main
from cellctl.config import CONFIG_ENV, load_config, project_root


@pytest.fixture
def elsewhere(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working directory outside the install, no $CELLCTL_CONFIG."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(CONFIG_ENV, raising=False)
    return tmp_path


def _write(path: Path, cell: str, extra: str = "") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"cell:\n  id: {cell}\n{extra}")
    return path


def test_flag_then_environment_then_working_directory(elsewhere: Path, monkeypatch, capsys) -> None:
    local = _write(elsewhere / "config" / "cell.yaml", "cellLocal")
    assert main(["validate"]) == 0
    out, err = capsys.readouterr()
    assert out.startswith(f"ok: {local} (cell 'cellLocal')")
    assert f"config {local} (./config/cell.yaml in the working directory)" in err
    env = _write(elsewhere / "env" / "e.yaml", "cellEnv")
    monkeypatch.setenv(CONFIG_ENV, str(env))
    assert main(["validate"]) == 0
    assert "cell 'cellEnv'" in capsys.readouterr().out
    flag = _write(elsewhere / "flag.yaml", "cellFlag")
    assert main(["cycles", "--config", str(flag)]) == 0
    assert f"cellctl cycles: config {flag} (named on the command line)" in capsys.readouterr().err


def test_relative_paths_follow_the_config_not_the_working_directory(elsewhere: Path, tmp_path: Path) -> None:
    """A cell folder outside the install: its own outputs; catalog, models and states from the install."""
    cfg_file = _write(tmp_path / "cellA" / "my.yaml", "cellA", "recording: {dir: out, index: out/c.db}\n")
    cfg = load_config(cfg_file)
    assert cfg.path(cfg.recording.index) == tmp_path / "cellA" / "out" / "c.db"
    assert cfg.path(cfg.catalog) == project_root() / "config" / "bins.yaml"
    assert cfg.path(cfg.classifier.models_dir) == project_root() / "models" / "classifier"
    assert main(["validate", str(cfg_file)]) == 0  # no states/ beside it: the shipped machines


def test_nothing_is_written_into_the_install(elsewhere: Path, capsys) -> None:
    """No config anywhere: the packaged defaults, but the cycle index goes under ./logs."""
    assert main(["cycles", "--last", "1"]) == 0
    assert (elsewhere / "logs" / "cells.db").is_file()
    err = capsys.readouterr().err
    assert f"config {project_root() / 'config' / 'cell.yaml'} (packaged defaults; outputs under ./logs)" in err


def test_hmi_users_go_beside_the_cell_config_not_into_the_install(elsewhere: Path, monkeypatch, capsys) -> None:
    import io

    _write(elsewhere / "config" / "cell.yaml", "cellLocal")
    monkeypatch.setattr("sys.stdin", io.StringIO("correct horse battery\n"))
    assert main(["hmi", "user", "add", "alice", "--role", "operator", "--password-stdin"]) == 0
    assert (elsewhere / "config" / "hmi.yaml").is_file()
    assert f"{elsewhere / 'config' / 'hmi.yaml'}: add alice" in capsys.readouterr().err
    assert not (project_root() / "config" / "hmi.yaml").exists()
