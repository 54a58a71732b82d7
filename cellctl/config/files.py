"""Where the config comes from: the install's root, which file a command reads, outputs kept out of the install."""

from __future__ import annotations

from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parent.parent.parent
"""The repository root of this checkout (``cellctl/config/files.py`` is three levels below it)."""


def project_root() -> Path:
    """The repository root of this checkout (holds ``config/``, ``states/``, ``models/``)."""
    return PROJECT_ROOT


def output_overrides(folder: Path | str) -> list[str]:
    """``--set`` overrides that keep a run's cycle logs, index and plan cache in ``folder``."""
    return [f"recording.dir={folder}", f"recording.index={folder}/cells.db", f"planner.plans_dir={folder}/plans"]


def default_config_path() -> Path:
    return PROJECT_ROOT / "config" / "cell.yaml"


CONFIG_ENV = "CELLCTL_CONFIG"
PACKAGED = "packaged defaults"
"""The source :func:`resolve_config_path` names when no config was found: outputs go under ``./logs``."""


def resolve_config_path(given: Path | str | None, cwd: Path | None = None) -> tuple[Path, str]:
    """The config file a command uses and where that choice came from, in this order:
    ``given`` (``--config``), ``$CELLCTL_CONFIG``, ``./config/cell.yaml`` in ``cwd`` (default: the
    working directory), else the packaged ``config/cell.yaml`` (source :data:`PACKAGED`: the caller
    moves the outputs out of the install, :func:`output_overrides`)."""
    import os

    if given:
        return Path(given), "named on the command line"
    if env := os.environ.get(CONFIG_ENV):
        return Path(env), f"${CONFIG_ENV}"
    local = (cwd or Path.cwd()) / "config" / "cell.yaml"
    if local.is_file():
        return local, "./config/cell.yaml in the working directory"
    return default_config_path(), PACKAGED
