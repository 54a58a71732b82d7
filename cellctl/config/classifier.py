"""The classifier worker and the verdict: the decision, enrolled detectors, re-looks, the per-face rule."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from cellctl.strict_model import ConfigModel as _Model
from cellctl.surface import SURFACES, Surface, per_surface


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
        default_factory=lambda: per_surface(0.6, 0.6),
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
