"""The cell configuration: YAML parsed into typed models that reject unknown keys.

``config/cell.yaml`` is the default simulated cell. Which file a command reads
(:func:`resolve_config_path`): ``--config``, else ``$CELLCTL_CONFIG``, else ``./config/cell.yaml``
in the working directory, else the packaged defaults with every output (logs, index, plans) under
``./logs`` — nothing is written into the install. Relative paths in a config file are resolved
against the config's own folder — the file's folder, or the folder above it when the file sits
in a ``config/`` folder (a cell's folder: ``config/``, ``logs/``, ``states/``) — never against the
working directory. Read-only resources the file does not name (the bin catalog, the classifier
models, ``states/``) come from the install when the config's folder has none.
"""

from __future__ import annotations

import typing
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import yaml
from pydantic import BaseModel, Field, StrictBool, ValidationError, field_validator, model_validator

from cellctl.bus.keys import ROLES, check_cell_id
from cellctl.errors import ConfigError
from cellctl.images import MAX_IMAGE_PIXELS, MIN_IMAGE_SIDE
from cellctl.review.config import ReviewConfig
from cellctl.strict_model import ConfigModel as _Model
from cellctl.surface import SURFACES, Surface

__all__ = [
    "BaseConfig",
    "BusConfig",
    "CameraConfig",
    "CellConfig",
    "NozzleConfig",
    "ClassifierConfig",
    "DetectorFiles",
    "PlannerConfig",
    "RecordingConfig",
    "RobotConfig",
    "SimConfig",
    "SupervisorConfig",
    "UrConfig",
    "UrControllerConfig",
    "UrFaultPolicy",
    "WashConfig",
    "BACKENDS",
    "apply_overrides",
    "backend_reading",
    "register_backend",
    "config_leaves",
    "default_config_path",
    "load_config",
    "output_overrides",
    "project_root",
    "resolve_config_path",
    "safe_yaml_load",
]

PROJECT_ROOT = Path(__file__).resolve().parent.parent


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


class BusConfig(_Model):
    """Zenoh endpoints. The daemon is a router listening on ``listen``; others are clients."""

    listen: list[str] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"], description="Zenoh endpoints the daemon's router listens on"
    )
    connect: list[str] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"], description="Zenoh endpoints workers and clients connect to"
    )
    lease_ms: int = Field(default=2000, ge=500, le=60000, description="link lease; bounds hang detection")
    zenoh_config: Path | None = Field(default=None, description="extra Zenoh json5 (tuning; loaded first)")
    multicast_scouting: StrictBool = Field(
        default=False, description="find peers by UDP multicast (off: only listed endpoints)"
    )
    security_dir: Path | None = Field(
        default=None, description="`cellctl secure init` folder: user/password auth, ACL, TLS (docs/security.md)"
    )
    principal: str | None = Field(
        default=None,
        pattern=r"^[a-z][a-z0-9_-]{0,63}$",
        description="who this client is on a secured bus; workers always use their role",
    )

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        # here, not when the session opens: `validate` must refuse what `run` cannot use
        from cellctl.bus.endpoints import check_endpoint

        return [check_endpoint(ep) for ep in v]


class Timeouts(_Model):
    """Seconds to wait for each worker op before declaring the worker hung."""

    default: float = Field(default=5.0, gt=0, description="any worker op not named below")
    approach: float = Field(default=60.0, gt=0, description="the base parking at a station")
    move: float = Field(default=60.0, gt=0, description="one robot move to a viewpoint")
    capture: float = Field(default=10.0, gt=0, description="one camera capture")
    classify: float = Field(default=10.0, gt=0, description="one classifier request")
    plan_submit: float = Field(default=5.0, gt=0, description="the planner accepting a job")
    plan_wait: float = Field(default=600.0, gt=0, description="a planner job to finish (supervisor.wait_for_plan)")
    stop: float = Field(default=2.0, gt=0, description="the robot acknowledging a stop")
    wash: float = Field(default=120.0, gt=0, description="one wash request: the transit to a sweep and its passes")
    wash_plan: float = Field(default=180.0, gt=0, description="a wash plan from the planner worker")


class SupervisorConfig(_Model):
    status_period_s: float = Field(default=1.0, gt=0, le=60, description="Status published at least this often")
    timeouts: Timeouts = Field(default_factory=Timeouts)
    required_workers: list[str] = Field(
        default_factory=lambda: ["robot", "camera", "classifier", "planner"],
        description="roles that must be alive for Start to be accepted",
    )
    on_worker_lost: Literal["abort", "hold"] = Field(
        default="abort", description="a required worker lost during Execute: Abort, or Hold until it is back"
    )
    identify_attempts: int = Field(default=3, ge=1, le=10, description="bin identifications tried before aborting")
    identify_views: int = Field(
        default=1, ge=1, le=5, description="observation poses fused per identification (>1 when one view is not enough)"
    )
    wait_for_plan: StrictBool = Field(default=False, description="wait for the planner job instead of replan_required")
    auto_reset: StrictBool = Field(default=False, description="Complete → Resetting → Idle without a PLC Reset")
    max_command_bytes: int = Field(default=64 * 1024, ge=256, description="a larger Command payload is refused")
    spawn_workers: list[str] = Field(
        default_factory=lambda: ["robot", "camera", "classifier", "planner"],
        description="roles started as child processes by `cellctl run --with-workers` and `cellctl demo`",
    )

    @field_validator("required_workers", "spawn_workers")
    @classmethod
    def _roles(cls, v: list[str]) -> list[str]:
        bad = [r for r in v if r not in ROLES]
        if bad:
            raise ValueError(f"unknown worker roles {bad}; expected some of {list(ROLES)}")
        return v


class RecordingConfig(_Model):
    dir: Path = Field(default=Path("logs"), description="folder of the per-cycle MCAP logs")
    index: Path = Field(default=Path("logs/cells.db"), description="SQLite index of recorded cycles")


class UrFaultPolicy(_Model):
    """What the UR backend treats as a fault (reported, token withdrawn, motion stopped)."""

    reduced_mode: StrictBool = Field(default=True, description="reduced (safety-scaled) mode is a fault")
    data_stale_ms: float = Field(default=90.0, gt=0, le=5000, description="no fresh RTDE data this long: a fault")
    monitor_hz: float = Field(default=100.0, ge=20, le=500, description="safety/joint poll rate of the worker")
    watchdog_hz: float = Field(default=5.0, ge=1, le=500, description="controller stops the program below this")


class UrConfig(_Model):
    """``robot.backend: ur`` — a UR10e over ur-rtde (RTDE 30004, script 30003, dashboard 29999)."""

    host: str = Field(default="127.0.0.1", description="controller address (ur-rtde fixes the ports)")
    expected_model: str = Field(default="UR10e", description="checked against the dashboard's model")
    expected_serial: str | None = Field(default=None, description="checked against the dashboard's serial")
    accel_fraction: float = Field(default=1.0, gt=0, le=1, description="of the motion module's acceleration limits")
    stop_decel: float = Field(default=4.0, gt=0, le=40, description="stopJ deceleration, rad/s² (leading axis)")
    connect_attempts: int = Field(default=4, ge=1, le=20, description="connect tries, back-off doubling from 0.25 s")
    tcp_warn_m: float = Field(default=0.005, gt=0, le=0.1, description="robot TCP vs model FK: warn above")
    joint_tolerance_rad: float = Field(default=0.002, gt=0, le=0.1, description="arrival check at a goal")
    twin: StrictBool = Field(
        default=False, description="the controller is `cellctl sim ur-controller`: publish the twin's SimState"
    )
    faults: UrFaultPolicy = Field(default_factory=UrFaultPolicy)


_Fields = TypeVar("_Fields", bound=type[_Model])

BACKENDS: dict[str, dict[str, type[_Model]]] = {}
"""Config section -> backend name -> the class of the fields only that backend reads (:func:`register_backend`)."""


def register_backend(section: str, name: str) -> Callable[[_Fields], _Fields]:
    """Register the decorated class as the fields backend ``name`` of ``section`` reads (LeRobot's
    ``register_subclass``). The section's model inherits every registered class of its section, so the
    YAML stays flat (``camera.device``); a test holds the two together."""

    def register(cls: _Fields) -> _Fields:
        known = BACKENDS.setdefault(section, {})
        if name in known:
            raise ValueError(f"{section}.backend {name!r} registered twice: {known[name].__name__}, {cls.__name__}")
        known[name] = cls
        return cls

    return register


def backend_reading(section: str, key: str) -> str | None:
    """The backend that alone reads ``section.key`` (``camera``, ``device`` -> ``opencv``); None: all do."""
    for name, fields in BACKENDS.get(section, {}).items():
        if key in fields.model_fields:
            return name
    return None


@register_backend("robot", "sim")
class SimRobotFields(_Model):
    """``robot.backend: sim`` — the pybullet twin's arm (and the twin's time)."""

    speed_scale: float = Field(default=1.0, gt=0, le=1000, description=">1 runs motions faster")


@register_backend("robot", "ur")
class UrRobotFields(_Model):
    """``robot.backend: ur`` — a UR10e over ur-rtde."""

    ur: UrConfig = Field(default_factory=UrConfig)


class RobotConfig(SimRobotFields, UrRobotFields):
    """The arm: ``backend`` picks the worker's implementation; fields only one backend reads are its
    registered class's (:data:`BACKENDS`)."""

    backend: Literal["sim", "ur"] = Field(default="sim", description="sim: the pybullet twin; ur: a UR10e (robot.ur)")
    speed_fraction: float = Field(default=0.5, gt=0, le=1, description="of the UR10e joint speed limits (sim and ur)")
    settle_s: float = Field(default=0.2, ge=0, le=10, description="wait after a move before it is reported done")
    joint_state_hz: float = Field(default=10.0, gt=0, le=500, description="rate the robot worker publishes JointState")
    # read by both planned backends (cellctl.workers.robot._planned), not only the sim
    plan_timeout_s: float = Field(default=3.0, gt=0, le=60, description="RRTConnect budget per move")
    collision_margin_m: float = Field(default=0.005, ge=0, le=0.1, description="clearance around the arm")
    hand_eye: Path | None = Field(
        default=None,
        description="T_flange_cam JSON from `cellctl calibrate hand-eye`; None: the nominal mount (robot_model)",
    )


@register_backend("camera", "sim")
class SimCameraFields(_Model):
    """``camera.backend: sim`` — the twin's renderer."""

    noise_sigma: float = Field(default=2.0, ge=0, le=50, description="sensor noise, 8-bit grey levels")


@register_backend("camera", "opencv")
class OpenCvCameraFields(_Model):
    """``camera.backend: opencv`` — a device or stream through OpenCV."""

    device: str = Field(default="0", description="device index or stream URL")


@register_backend("camera", "folder")
class FolderCameraFields(_Model):
    """``camera.backend: folder`` — replays images from a folder."""

    folder: Path | None = Field(default=None, description="directory of images to replay")


class CameraConfig(SimCameraFields, OpenCvCameraFields, FolderCameraFields):
    """The camera: ``backend`` picks the worker's implementation; fields only one backend reads are its
    registered class's (:data:`BACKENDS`)."""

    backend: Literal["sim", "opencv", "folder"] = Field(
        default="sim", description="sim: the twin's renderer; opencv: a device or stream; folder: replay images"
    )
    width: int = Field(default=1280, gt=0, description="image width, px")
    height: int = Field(default=720, gt=0, description="image height, px")
    format: Literal["png", "jpeg"] = Field(default="png", description="image encoding on the wire")
    fx: float | None = Field(default=None, gt=0, description="px; None: D435 colour defaults scaled to width")
    fy: float | None = Field(default=None, gt=0, description="px; None: same as fx")
    cx: float | None = Field(default=None, description="px; None: image centre")
    cy: float | None = Field(default=None, description="px; None: image centre")
    max_image_pixels: int = Field(
        default=MAX_IMAGE_PIXELS,
        ge=MIN_IMAGE_SIDE * MIN_IMAGE_SIDE,
        description="pixel budget (width × height) of any image decoded (captures, classify, folder), checked "
        "from the PNG/JPEG header before decoding; a bigger one is refused (decompression bombs)",
    )


class NozzleConfig(_Model):
    """The washing nozzle (:class:`cellctl.washing.nozzle.NozzleModel`), a second tool beside the camera."""

    half_angle_deg: float = Field(default=12.0, gt=0, lt=60, description="spray cone half-angle")
    working_distance_m: tuple[float, float] = Field(default=(0.15, 0.5), description="near, far stand-off (m)")
    max_incidence_deg: float = Field(default=60.0, gt=0, lt=90, description="jet vs face normal, at most")
    footprint_m: float = Field(default=0.05, gt=0, le=1, description="diameter of the spot one pass cleans")
    removal_per_pass: float = Field(default=0.8, gt=0, le=1, description="fraction of the powder one pass removes")
    clean_residual: float = Field(default=0.05, gt=0, lt=1, description="powder fraction that may stay")
    overlap: float = Field(default=0.3, ge=0, lt=0.9, description="raster line overlap, fraction of the footprint")
    mount_xyz_rpy: tuple[float, float, float, float, float, float] = Field(
        default=(0.0, 0.0, 0.25, 0.0, 0.0, 0.0), description="nozzle tip in the flange frame: m, m, m, deg, deg, deg"
    )
    lance_radius_m: float = Field(default=0.015, gt=0, lt=0.1, description="lance radius (m): its body clearance")
    # Whether the fields make a nozzle that works (its footprint, reach, clearance) is the nozzle model's check
    # (cellctl.washing.nozzle.NozzleModel), run by the composition root (cellctl.app.preflight) and its factory.


class WashConfig(_Model):
    """Wash-and-verify (cellctl.washing): which faces to wash and how many rounds."""

    threshold: float = Field(default=0.5, gt=0, lt=1, description="face dirt probability that is washed")
    margin_m: float = Field(default=0.02, ge=0, le=0.3, description="targets dilated by this much around dirt")
    max_rounds: int = Field(default=3, ge=1, le=20, description="wash → re-inspect rounds before 'dirty'")
    splash_m: float = Field(
        default=0.05, ge=0, le=0.5, description="re-inspect the washed faces' neighbours this far (the jet splashes)"
    )
    # a clean verdict covers only what the cell saw; below this share of the bin's area (both
    # surfaces) no dirt seen is not a clean bin: `dirty`, reason "unverified" (docs/washing/README.md)
    min_seen_fraction: float = Field(
        default=0.6,
        ge=0,
        le=1,
        description="`clean` needs the scan and re-inspections to have seen this share of the bin's area",
    )


def _per_surface(external: float, internal: float) -> dict[Surface, float]:
    return {"external": external, "internal": internal}


class VerdictConfig(_Model):
    """How a cycle's per-face dirt evidence becomes the bin verdict (docs/classifier/inspect.md)."""

    # "faces" by default since the detector became the default decision (issue 31): with it the any-view
    # rule called every clean bin dirty (68/68 on bench inspect, round 6; 14 of 72 views of the shipped
    # whole-bin twin cycle) — a rule that fails every clean bin is no rule. Faces, round 6: false-clean
    # 10/132, false-dirty 1/68 (docs/decisions.md, "The verdict rule follows the detector").
    rule: Literal["faces", "views"] = Field(
        default="faces", description="faces: fused per-face probabilities; views: dirty if any view is dirty"
    )
    # a face's verdict depends on logit(face_threshold) - logit(face_prior) only: 0.5 / 0.1 and 0.7 / 0.2
    # (2.20 / 2.23) decided the same bins on the round 6 validation bench; patches there: false-clean
    # 4/64 -> 1/64 (docs/classifier/inspect.md)
    face_threshold: float = Field(default=0.5, gt=0, lt=1, description="a face is dirty at this fused probability")
    min_dirty_area_cm2: float = Field(default=0.0, ge=0, description="faces rule: dirty only above this dirty area")
    face_prior: float = Field(default=0.1, gt=0, lt=1, description="prior dirt probability of a face")
    projection: Literal["patches", "samples"] = Field(
        default="patches",
        description="patches: a face-index render of each view carries every heat-map patch onto the face cells its "
        "rays hit; samples: four sample points per face looked up in the heat map (before round 6)",
    )
    face_cells: int = Field(default=4, ge=1, le=16, description="patches: a face is fused as cells² barycentric cells")
    patch_share: float = Field(
        default=0.25,
        ge=0,
        le=1,
        description="patches: a hot patch gives a face its full dirty evidence once the face fills this share of the "
        "patch's on-bin rays, less below (0: always full)",
    )
    board_margin_m: float = Field(
        default=0.03,
        ge=0,
        le=0.2,
        description="patches: heat-map patches whose rays hit the ID board or this margin around it give no evidence",
    )
    # 0.6 each: the catalog's and the foreign bins' whole-bin plans see at worst 65 % of the tote's external surface
    # (its bottom stands on the floor) and 72 % of the case study's internal one at the planner's floors
    # (planner.whole.min_bound_pct); 0.6 leaves a refused view or two of room, while one station's one surface
    # (34 % of the case study) or a hopper the arm cannot look into (44 % internal) is `incomplete`
    # (docs/decisions.md, "Whole bin by default")
    min_seen_fraction: dict[Surface, Annotated[float, Field(ge=0, le=1)]] = Field(
        default_factory=lambda: _per_surface(0.6, 0.6),
        description="per surface, the share of its area the cycle must have seen for `clean`; below it a cycle "
        "that saw no dirt ends `incomplete` (0 / absent: no minimum)",
    )


class RelookConfig(_Model):
    """Re-imaging an uncertain viewpoint from a nearby pose within the same cycle."""

    max_views: int = Field(default=4, ge=0, le=64, description="re-looks per cycle (0: off)")
    offset_m: float = Field(default=0.03, ge=0, le=0.2, description="sideways shift of the camera")
    glance_deg: float = Field(default=12.0, ge=0, le=45, description="swing about the point looked at")
    depth_m: float = Field(default=0.35, gt=0, le=2, description="distance of that point ahead of the camera")
    confirm_dirty: Literal["off", "whole_bin", "on"] = Field(
        default="whole_bin",
        description="re-look once at a view called dirty with certainty; a certain-clean re-look overrules it "
        "(whole_bin: in whole-bin cycles only, where one false-dirty view in ~100 decides the bin)",
    )


class DetectorFiles(_Model):
    """Site-enrolled detector files (`cellctl detector enroll`), per surface; None: the shipped one."""

    external: Path | None = Field(default=None, description="enrolled detector of the external surface")
    internal: Path | None = Field(default=None, description="enrolled detector of the internal surface")


class ClassifierConfig(_Model):
    backend: Literal["torch"] = Field(default="torch", description="the classifier worker's implementation")
    # The detector is the default (issue 31): on two clean/dirty generators made outside the project the
    # supervised whole-image model passed 22-72 % of dirty images as clean (external 22-28 % and 72 %,
    # internal 40 %), the detector 0-16 %; its weakness, false alarms on a steel it never saw, is what
    # site enrollment (classifier.detector_files) fixes. "supervised" stays selectable (docs/decisions.md).
    decision: Literal["auto", "detector", "supervised"] = Field(
        default="detector",
        description="detector: supervised patch head + clean-only bank (<surface>.detect.pt or detector_files; "
        "the worker refuses to start without them); auto: it when present; supervised: the whole-image model",
    )
    detector_files: DetectorFiles = Field(
        default_factory=DetectorFiles,
        description="per surface, a site-enrolled detector file (`cellctl detector enroll`) that replaces the "
        "shipped <surface>.detect.pt; relative paths resolve like every config path",
    )
    verdict: VerdictConfig = Field(default_factory=VerdictConfig)
    relook: RelookConfig = Field(default_factory=RelookConfig)
    references: bool = Field(
        default=True,
        description="judge each view of a commissioned plan against its reference (issue 34); false: the detector "
        "alone, as before commissioning (docs/classifier/reference.md has the measured trade-off)",
    )
    mask_cabin: list[Surface] = Field(
        default_factory=lambda: list[Surface](["internal"]),
        description="surfaces whose views have the pixels off the bin (the cabin past the rim) filled before "
        "classification: the internal model learned the cavity, and called the lit cabin past the rim dirty",
    )
    models_dir: Path = Field(default=Path("models/classifier"), description="folder of the shipped classifier models")
    imagenet_weights: Path | None = Field(default=None, description="optional local torchvision ResNet18 state_dict")
    variant: Literal["fp32", "fused"] = Field(
        default="fused", description="fused: batch norm folded + frozen graph (same outputs, faster)"
    )
    max_batch: int = Field(default=16, ge=1, le=256, description="queued classify requests run as one batch")
    threads: int | None = Field(
        default=None,
        ge=1,
        le=256,
        description="inference CPU threads: torch (default: all cores) and ONNX Runtime intra-op (default: 1 on "
        "a 2-core host, else 2; cellctl.classify.runtime.default_threads)",
    )
    runtime: Literal["auto", "onnx", "torch"] = Field(
        default="auto",
        description="what runs the detector's networks: onnx = ONNX Runtime on <surface>.detect.onnx (`cellctl "
        "detector export`), torch = PyTorch, auto = onnx when the export exists (a stale export is refused)",
    )
    dataset_dir: Path = Field(default=Path("data/collected"), description="collect mode: where images are stored")

    @model_validator(mode="after")
    def _enrolled_files_need_the_detector(self) -> ClassifierConfig:
        given = [s for s in SURFACES if getattr(self.detector_files, s) is not None]
        if given and self.decision == "supervised":
            raise ValueError(
                f"detector_files {given} name enrolled detectors but decision is 'supervised'; "
                "set classifier.decision to 'detector' or 'auto'"
            )
        return self


class PoseTolerance(_Model):
    """How far the measured bin pose (robot base frame) may be from a plan's and still be adjusted.

    Two parks differ by up to twice the base's parking error (plus the lever of its yaw error),
    so the tolerance must exceed that, or every cycle replans.
    """

    translation_mm: float = Field(default=80.0, gt=0, description="bin position difference, mm")
    rotation_deg: float = Field(default=4.0, gt=0, description="bin orientation difference, deg")


class WholeBinConfig(_Model):
    """Whole-bin plans (cellctl.planning.stations / whole): stations around the bin, cycle-time model."""

    enabled: StrictBool = Field(
        default=True,
        description="the cycle visits every station of the newest whole-bin plan and scans both surfaces; "
        "false: one station, one surface (planner.surface), which classifier.verdict.min_seen_fraction calls "
        "`incomplete` rather than `clean`",
    )
    candidates: int = Field(default=8, ge=1, le=36, description="station candidates around the bin")
    max_stations: int = Field(default=4, ge=1, le=36, description="stations a whole-bin plan may use")
    park_distance_m: float = Field(default=0.75, gt=0, le=3, description="base origin beyond the bin's extent")
    min_station_gain_pct: float = Field(
        default=2.0, ge=0, lt=100, description="% of a surface's bound a station must add"
    )
    view_min_gain_pct: float = Field(
        default=0.15, ge=0, lt=100, description="% of a surface's bound a viewpoint must add"
    )
    allowed_deg: list[float] | None = Field(
        default=None, description="approach directions the base may use (deg, bin frame; -90 = board side); None: all"
    )
    cabin_half_m: tuple[float, float] = Field(default=(2.5, 2.5), description="cabin half-extents x, y (m)")
    bin_in_cabin: tuple[float, float, float] = Field(
        default=(0.0, 0.0, 0.0), description="bin footprint x, y (m) and yaw (deg) in the cabin"
    )
    settle_s: float = Field(default=0.5, ge=0, le=10, description="modelled settle per viewpoint (paper: 1 s)")
    capture_s: float = Field(default=0.1, ge=0, le=10, description="modelled capture per viewpoint")
    base_speed_m_s: float = Field(default=0.5, gt=0, le=3, description="modelled base travel speed")
    base_turn_deg_s: float = Field(default=45.0, gt=0, le=360, description="modelled base turn rate")
    park_s: float = Field(default=3.0, ge=0, le=60, description="docking time per station")
    inner_candidates: int = Field(
        default=4, ge=0, le=36, description="directions of the inner station ring (0: outer ring only)"
    )
    inner_park_distance_m: float = Field(
        default=0.35, gt=0, le=3, description="inner ring: base origin beyond the bin's extent (reach into deep bins)"
    )
    odometry_error_m: float = Field(
        default=0.01,
        ge=0,
        le=0.2,
        description="a station without the board: extra clearance of its configurations from the bin, for the "
        "error of the pose the base's odometry carries there (two base.localisation_error reports); 0: none",
    )
    chains: Literal["all", "needed"] = Field(
        default="needed",
        description="a viewpoint joined to home through others: visit its chain's viewpoints only where its tour "
        "needs them (the selection makes up what they saw) or always (all)",
    )
    min_bound_pct: dict[Surface, Annotated[float, Field(ge=0, le=100)]] = Field(
        default_factory=lambda: _per_surface(91.0, 86.0),
        description="per surface, % of its upper bound the selection must see: below it viewpoints are added past "
        "view_min_gain_pct (0 / absent: no floor)",
    )
    cycle_budget_s: float = Field(
        default=180.0,
        ge=0,
        le=3600,
        description="takt for one bin's modelled cycle (s): a plan above it takes one station fewer where the floors "
        "(min_bound_pct) still hold, then drops the viewpoints that see least per second down to the floors; 0: none",
    )


class PlannerConfig(_Model):
    plans_dir: Path = Field(default=Path("models/plans"), description="folder of the plan cache")
    tolerance: PoseTolerance = Field(default_factory=PoseTolerance)
    surface: Surface = Field(default="external", description="the surface a single-station cycle scans")
    seed_pct: float = Field(default=10.0, gt=0, le=100, description="% of the surface's faces used as viewpoint seeds")
    mode: Literal["fast", "paper"] = Field(
        default="fast", description="fast: the project's planner; paper: the paper's RRT* baseline"
    )
    seed: int = Field(default=0, description="random seed of the planner (same seed, same plan)")
    whole: WholeBinConfig = Field(default_factory=WholeBinConfig)


class UrControllerConfig(_Model):
    """``cellctl sim ur-controller``: the emulated UR10e controller (a twin component)."""

    host: str = Field(default="127.0.0.1", description="loopback address it listens on (127.0.0.0/8)")
    control_port: int = Field(default=30099, ge=1024, le=65535, description="fault-injection text socket")
    model: str = Field(default="UR10", description="model name the dashboard reports")
    serial: str = Field(default="20235500001", description="serial number the dashboard reports")
    polyscope: str = Field(default="5.11.1.108318", description="PolyScope version it reports (e-Series: 5.x)")
    robot_mode: Literal["RUNNING", "IDLE", "POWER_OFF"] = Field(default="RUNNING", description="robot mode at start")
    remote_control: StrictBool = Field(default=True, description="the pendant is in remote control (RTDE may drive it)")
    unlock_delay_s: float = Field(default=5.0, ge=0, le=60, description="protective stop: unlock after (s)")
    stop_decel: float = Field(default=10.0, gt=0, le=40, description="safety stops' deceleration, rad/s²")


@register_backend("base", "sim")
class SimBaseFields(_Model):
    """``base.backend: sim`` — the twin parks the base (no fields of its own)."""


@register_backend("base", "manual")
class ManualBaseFields(_Model):
    """``base.backend: manual`` — an operator or the PLC parks the base and confirms."""

    confirm_timeout_s: float = Field(default=300.0, gt=0, le=3600, description="wait for the confirmation")


class BaseConfig(SimBaseFields, ManualBaseFields):
    """The mobile base: ``sim`` (the twin parks it) or ``manual`` (an operator/PLC parks and confirms)."""

    backend: Literal["sim", "manual"] = Field(default="sim", description="sim: the twin parks it; manual: confirmed")
    # An AMR docking on its markers repeats to a few mm; its map pose is what carries the bin pose to a
    # station that cannot see the board (bin_pose_source base_odometry), so its error bounds the cycle's there.
    localisation_error_m: float = Field(
        default=0.005, ge=0, le=0.5, description="error of the parked pose the base reports (sim: drawn per park)"
    )
    localisation_error_deg: float = Field(
        default=0.2, ge=0, le=30, description="yaw error of the parked pose the base reports (sim: drawn per park)"
    )


class SimConfig(_Model):
    """The pybullet twin's scenario (used by sim backends only)."""

    bin_type: str = Field(default="case_study", description="catalog bin the twin shows")
    bin_pose_xyz_yaw: tuple[float, float, float, float] = Field(
        default=(0.0, 0.0, 0.0, 0.0), description="bin pose in the world: x, y, z (m), yaw (deg)"
    )
    dirty: StrictBool = Field(default=False, description="the twin's bin carries powder")
    powder_amount: float = Field(default=0.5, ge=0, le=1, description="how much powder a dirty bin carries (0..1)")
    seed: int = Field(default=0, description="random seed of the scenario (powder, parking errors)")
    approach_error_m: float = Field(default=0.02, ge=0, le=0.5, description="parking position error, radius (m)")
    approach_error_deg: float = Field(default=1.0, ge=0, le=30, description="parking yaw error, ± deg")
    ur_controller: UrControllerConfig = Field(default_factory=UrControllerConfig)


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


class _Loader(yaml.SafeLoader):
    """safe_load, but only true/false are booleans (``on``/``off``/``yes``/``no`` stay strings)."""


_Loader.yaml_implicit_resolvers = {
    k: [(tag, rx) for tag, rx in v if tag != "tag:yaml.org,2002:bool"]
    for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
for _first in "tTfF":
    _Loader.add_implicit_resolver(
        "tag:yaml.org,2002:bool",
        __import__("re").compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
        list(_first),
    )


class _DuplicateKey(yaml.YAMLError):
    """A mapping names one key twice: YAML lets the last one win silently, we refuse it."""


def _mapping_without_duplicates(loader: _Loader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    first: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            line = first.setdefault(key, key_node.start_mark.line)
        except TypeError:  # an unhashable key: construct_mapping says so
            continue
        if line != key_node.start_mark.line:
            raise _DuplicateKey(
                f"duplicate key {key!r} at line {key_node.start_mark.line + 1} (first at line {line + 1}); "
                "give each key once"
            )
    return loader.construct_mapping(node, deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_without_duplicates)


def safe_yaml_load(text: str, source: str = "<string>") -> Any:
    """Parse YAML safely; raise ConfigError with the location on syntax errors."""
    try:
        return yaml.load(text, Loader=_Loader)  # _Loader derives from SafeLoader
    except yaml.YAMLError as err:
        raise ConfigError(f"{source}: not valid YAML: {err}") from err


def _allowed_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str] | None:
    """Field names of the model that holds the key at ``loc`` (for 'unknown key' messages)."""
    current: Any = model
    for part in loc[:-1]:
        if not (isinstance(current, type) and issubclass(current, BaseModel)):
            return None
        field = current.model_fields.get(str(part))
        if field is None:
            return None
        current = field.annotation
        for arg in typing.get_args(current) or ():
            if isinstance(arg, type) and issubclass(arg, BaseModel):
                current = arg
    if isinstance(current, type) and issubclass(current, BaseModel):
        return sorted(k for k in current.model_fields if k != "root")
    return None


def explain_validation(err: ValidationError, model: type[BaseModel], source: str) -> str:
    """One line per problem: key path, what is wrong, the value given, what is allowed."""
    lines = []
    for e in err.errors():
        loc = tuple(e["loc"])
        key = ".".join(str(x) for x in loc) or "(top level)"
        if e["type"] == "extra_forbidden":
            allowed = _allowed_keys(model, loc)
            lines.append(f"{source}: unknown key {key!r}; allowed keys here: {allowed}")
        else:
            given = e.get("input")
            shown = repr(given)
            if len(shown) > 80:
                shown = shown[:77] + "..."
            lines.append(f"{source}: key {key!r}: {e['msg']} (got {shown})")
    return "\n".join(lines)


def _set_dotted(data: dict[str, Any], dotted: str, raw_value: str) -> None:
    if "=" in dotted and raw_value == "":
        dotted, raw_value = dotted.split("=", 1)
    parts = dotted.split(".")
    node = data
    for p in parts[:-1]:
        nxt = node.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"--set {dotted}: {p!r} is not a section")
        node = nxt
    node[parts[-1]] = safe_yaml_load(raw_value, f"--set {dotted}")


def apply_overrides(data: dict[str, Any], overrides: list[str] | None, flag: str = "--set") -> None:
    """Apply ``key.path=value`` strings (values parsed as YAML) to a parsed config mapping.

    Raises:
        ConfigError: an override has no ``=`` or names a key below a non-section.
    """
    for ov in overrides or []:
        if "=" not in ov:
            raise ConfigError(f"{flag} {ov!r}: expected KEY.PATH=VALUE")
        k, v = ov.split("=", 1)
        _set_dotted(data, k.strip(), v)


def load_config(path: Path | str | None = None, overrides: list[str] | None = None) -> CellConfig:
    """Load and validate a cell config.

    Args:
        path: YAML file; ``None`` means the default ``config/cell.yaml``.
        overrides: ``key.path=value`` strings applied after the file (``--set``).

    Raises:
        ConfigError: the file is missing, not YAML, or does not validate; the message names
            every offending key, its value and what is allowed.
    """
    p = Path(path) if path is not None else default_config_path()
    if not p.is_file():
        raise ConfigError(f"config file {str(p)!r} does not exist")
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{p}: not a YAML text file (byte {err.start} is not UTF-8 text)") from None
    data = safe_yaml_load(text, str(p))
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: top level must be a mapping of sections, got {type(data).__name__}")
    apply_overrides(data, overrides)
    root = p.resolve().parent
    if root.name == "config":
        root = root.parent
    try:
        cfg = CellConfig.model_validate({**data, "root": root})
    except ValidationError as err:
        raise ConfigError(explain_validation(err, CellConfig, str(p))) from err
    # a cell folder outside the install names what it has; what it does not name is the install's
    if "catalog" not in data and not cfg.path(cfg.catalog).exists():
        cfg.catalog = PROJECT_ROOT / cfg.catalog
    if "models_dir" not in (data.get("classifier") or {}) and not cfg.path(cfg.classifier.models_dir).exists():
        cfg.classifier.models_dir = PROJECT_ROOT / cfg.classifier.models_dir
    return cfg


def _section_model(annotation: Any) -> type[BaseModel] | None:
    """The config section a field holds (``RobotConfig``; also through ``X | None``), or None for a leaf."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (list, dict, tuple):
        return None
    for arg in typing.get_args(annotation):
        found = _section_model(arg)
        if found is not None:
            return found
    return None


def config_leaves(
    model: type[BaseModel] | None = None, prefix: str = "", backend: str | None = None
) -> list[tuple[str, Any, str]]:
    """Every settable leaf of the cell config: ``(dotted key, default, description)``, in model order; the
    description of a leaf only one backend reads starts with that backend (``opencv: …``, from :data:`BACKENDS`).

    What ``cellctl schema --config`` prints; a test holds every leaf to a description.
    """
    rows: list[tuple[str, Any, str]] = []
    for name, field in (model or CellConfig).model_fields.items():
        if field.exclude:
            continue
        owner = backend or (backend_reading(prefix.rstrip("."), name) if prefix.count(".") == 1 else None)
        section = _section_model(field.annotation)
        if section is not None:
            rows += config_leaves(section, f"{prefix}{name}.", owner)
        else:
            default = field.get_default(call_default_factory=True)
            text = field.description or ""
            rows.append((f"{prefix}{name}", default, f"{owner}: {text}" if owner and text else text))
    return rows
