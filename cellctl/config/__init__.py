"""The cell configuration: YAML parsed into typed models that reject unknown keys.

``config/cell.yaml`` is the default simulated cell. Which file a command reads
(:func:`resolve_config_path`): ``--config``, else ``$CELLCTL_CONFIG``, else ``./config/cell.yaml``
in the working directory, else the packaged defaults with every output (logs, index, plans) under
``./logs`` — nothing is written into the install. Relative paths in a config file are resolved
against the config's own folder — the file's folder, or the folder above it when the file sits
in a ``config/`` folder (a cell's folder: ``config/``, ``logs/``, ``states/``) — never against the
working directory. Read-only resources the file does not name (the bin catalog, the classifier
models, ``states/``) come from the install when the config's folder has none.

A leaf: the package imports no domain module (``tests/test_config_leaf.py``); checks across a
model's fields that need the domain's models run in the composition root or the factories.
Modules, one concept each (``from cellctl.config import X`` is the way in):

- :mod:`.files`: the install's root, which config file a command reads, outputs kept out of the install;
- :mod:`.backends`: per-backend fields registered by name (:func:`register_backend`, :data:`BACKENDS`);
- :mod:`.daemon` (bus, supervisor and its timeouts, recording), :mod:`.robot` (arm, mobile base),
  :mod:`.camera`, :mod:`.washing` (nozzle, wash rounds), :mod:`.classifier` (and the verdict),
  :mod:`.planner` (and whole-bin plans), :mod:`.sim` (the twin): the sections;
- :mod:`.cell`: :class:`CellConfig`, one field per section;
- :mod:`.loading`: safe YAML, ``--set`` overrides, :func:`load_config`, errors that name the key;
- :mod:`.leaves`: :func:`config_leaves`, what ``cellctl schema --config`` prints.
"""

from cellctl.config.backends import BACKENDS, backend_reading, register_backend
from cellctl.config.camera import CameraConfig, FolderCameraFields, OpenCvCameraFields, SimCameraFields
from cellctl.config.cell import CellConfig, CellSection
from cellctl.config.classifier import ClassifierConfig, DetectorFiles, RelookConfig, VerdictConfig
from cellctl.config.daemon import BusConfig, RecordingConfig, SupervisorConfig, Timeouts
from cellctl.config.files import (
    CONFIG_ENV,
    PACKAGED,
    PROJECT_ROOT,
    default_config_path,
    output_overrides,
    project_root,
    resolve_config_path,
)
from cellctl.config.leaves import config_leaves
from cellctl.config.loading import apply_overrides, explain_validation, load_config, safe_yaml_load
from cellctl.config.planner import PlannerConfig, PoseTolerance, WholeBinConfig
from cellctl.config.robot import (
    BaseConfig,
    ManualBaseFields,
    RobotConfig,
    SimBaseFields,
    SimRobotFields,
    UrConfig,
    UrFaultPolicy,
    UrRobotFields,
)
from cellctl.config.sim import SimConfig, UrControllerConfig
from cellctl.config.washing import NozzleConfig, WashConfig

__all__ = [
    "BACKENDS",
    "BaseConfig",
    "BusConfig",
    "CONFIG_ENV",
    "CameraConfig",
    "CellConfig",
    "CellSection",
    "ClassifierConfig",
    "DetectorFiles",
    "FolderCameraFields",
    "ManualBaseFields",
    "NozzleConfig",
    "OpenCvCameraFields",
    "PACKAGED",
    "PROJECT_ROOT",
    "PlannerConfig",
    "PoseTolerance",
    "RecordingConfig",
    "RelookConfig",
    "RobotConfig",
    "SimBaseFields",
    "SimCameraFields",
    "SimConfig",
    "SimRobotFields",
    "SupervisorConfig",
    "Timeouts",
    "UrConfig",
    "UrControllerConfig",
    "UrFaultPolicy",
    "UrRobotFields",
    "VerdictConfig",
    "WashConfig",
    "WholeBinConfig",
    "apply_overrides",
    "backend_reading",
    "config_leaves",
    "default_config_path",
    "explain_validation",
    "load_config",
    "output_overrides",
    "project_root",
    "register_backend",
    "resolve_config_path",
    "safe_yaml_load",
]
