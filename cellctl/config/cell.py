"""The whole configuration of one cell: :class:`CellConfig`, one field per section."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, field_validator

from cellctl.bus.keys import check_cell_id
from cellctl.config.camera import CameraConfig
from cellctl.config.classifier import ClassifierConfig
from cellctl.config.daemon import BusConfig, RecordingConfig, SupervisorConfig
from cellctl.config.files import PROJECT_ROOT
from cellctl.config.planner import PlannerConfig
from cellctl.config.robot import BaseConfig, RobotConfig
from cellctl.config.sim import SimConfig
from cellctl.config.washing import NozzleConfig, WashConfig
from cellctl.errors import ConfigError
from cellctl.review.config import ReviewConfig
from cellctl.strict_model import ConfigModel as _Model


class CellSection(_Model):
    id: str = Field(default="cell1", description="the cell's id in every key expression (cell/<id>/...)")

    @field_validator("id")
    @classmethod
    def _id(cls, v: str) -> str:
        try:
            return check_cell_id(v)
        except ConfigError as err:
            raise ValueError(str(err)) from None


class CellConfig(_Model):
    """The whole configuration of one cell."""

    cell: CellSection = Field(default_factory=CellSection)
    bus: BusConfig = Field(default_factory=BusConfig)
    supervisor: SupervisorConfig = Field(default_factory=SupervisorConfig)
    recording: RecordingConfig = Field(default_factory=RecordingConfig)
    catalog: Path = Field(default=Path("config/bins.yaml"), description="the bin catalog (types, meshes, boards)")
    robot: RobotConfig = Field(default_factory=RobotConfig)
    base: BaseConfig = Field(default_factory=BaseConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    nozzle: NozzleConfig = Field(default_factory=NozzleConfig)
    wash: WashConfig = Field(default_factory=WashConfig)
    classifier: ClassifierConfig = Field(default_factory=ClassifierConfig)
    planner: PlannerConfig = Field(default_factory=PlannerConfig)
    sim: SimConfig = Field(default_factory=SimConfig)
    review: ReviewConfig = Field(default_factory=ReviewConfig)

    root: Path = Field(default=PROJECT_ROOT, exclude=True, description="base of relative paths")
    # The hand-eye file robot.hand_eye names is read and checked by cellctl.vision.handeye.configured_hand_eye
    # (run by cellctl.app.preflight, so `validate`/`run` refuse a bad one before the first move).

    @property
    def cell_id(self) -> str:
        return self.cell.id

    def path(self, p: Path | str) -> Path:
        """Resolve a config path against the project root."""
        q = Path(p)
        return q if q.is_absolute() else self.root / q
