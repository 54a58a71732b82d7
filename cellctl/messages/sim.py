"""The twin only: the scenario and its ground truth (the supervisor must not use them)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, model_validator

from cellctl.messages.base import PoseMsg, WireMessage, now_iso


class SimStateRequest(WireMessage):
    """Ask the sim robot worker for the current sim state (``keys.sim_state``)."""

    type: Literal["cellctl/SimStateRequest"] = "cellctl/SimStateRequest"
    v: Literal[1] = 1
    washes: bool = Field(default=False, description="also send the spray passes run so far (the camera renders them)")


class SimScenarioRequest(WireMessage):
    """Change the sim scenario at run time (op ``robot/scenario``); None leaves a field as is."""

    type: Literal["cellctl/SimScenarioRequest"] = "cellctl/SimScenarioRequest"
    v: Literal[1] = 1
    bin_type: str | None = None
    bin_xyz_yaw: tuple[float, float, float, float] | None = Field(
        default=None, description="bin footprint x, y (m), lift z (m), yaw (rad) in the world frame"
    )
    park_offset_xy_yaw: tuple[float, float, float] | None = Field(
        default=None, description="systematic parking offset x, y (m), yaw (rad) in the base frame (obstacle)"
    )
    dirty: bool | None = None
    powder_amount: float | None = Field(default=None, ge=0.0, le=1.0)
    seed: int | None = None
    repark: bool = Field(default=False, description="park the base again now (arm goes home first)")


class SimState(WireMessage):
    """The sim world now: scenario, true poses (ground truth) and the arm's joints."""

    type: Literal["cellctl/SimState"] = "cellctl/SimState"
    v: Literal[1] = 1
    bin_type: str
    bin_xyz_yaw: tuple[float, float, float, float]
    park_offset_xy_yaw: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dirty: bool
    powder_amount: float
    seed: int
    world_T_bin: PoseMsg
    world_T_base: PoseMsg
    parked: bool
    joints: list[float]
    moving: bool = False
    wash_passes: int = Field(default=0, ge=0, description="spray passes run over the bin since the scenario was set")
    washes: list[SprayPassMsg] | None = Field(
        default=None, description="the spray passes themselves, only when the request asked (SimStateRequest.washes)"
    )
    stamp: str = Field(default_factory=now_iso)


class SprayPassMsg(BaseModel):
    """One pass of the washing jet over the bin, in the **bin** frame (twin ground truth).

    As :class:`cellctl.sim.ground_truth.SprayPass`: the spot's path on the surface and the
    jet's direction at each spot.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    spots: list[tuple[FiniteFloat, FiniteFloat, FiniteFloat]] = Field(min_length=1, max_length=5000)
    axes: list[tuple[FiniteFloat, FiniteFloat, FiniteFloat]] = Field(min_length=1, max_length=5000)
    radius: FiniteFloat = Field(gt=0, le=1)
    cos_incidence: FiniteFloat = Field(ge=0, le=1)
    removal: FiniteFloat = Field(gt=0, le=1)

    @model_validator(mode="after")
    def _paired(self) -> SprayPassMsg:
        if len(self.spots) != len(self.axes):
            raise ValueError(f"a spray pass has {len(self.spots)} spots but {len(self.axes)} axes; expected one each")
        return self
