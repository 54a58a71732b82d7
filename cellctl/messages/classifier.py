"""The classifier worker's ops: classify (against a reference or not), its models, enrolling a detector."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from cellctl.messages.base import PoseMsg, WireMessage
from cellctl.messages.camera import Intrinsics
from cellctl.surface import Surface

ReferenceReason = Literal[
    "aligned",
    "no_reference",
    "no_fusion",
    "unreadable",
    "out_of_tolerance",
    "degenerate_prior",
    "ecc_not_converged",
    "low_correlation",
    "far_from_prior",
    "small_overlap",
]
"""Why a view was (``aligned``) or was not judged against its reference: the alignment's reject reasons
(:data:`cellctl.classify.reference.REJECT_REASONS`), ``no_fusion`` (the worker has no fitted
``<surface>.reference.json``), ``unreadable`` (the stored image is missing or not the manifest's)."""


class ClassifyReference(BaseModel):
    """The stored reference a classify request asks the view to be compared with (issue 34).

    Poses are in the bin frame (``frame_id 'bin'``): each camera relative to the bin pose measured
    in its own cycle, so a bin parked elsewhere moves neither. The plane is the viewed wall in the
    reference camera's frame (from the bin mesh; the set stores no depth).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    image: str = Field(max_length=4096, description="the reference image's path on the worker's host")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="as the set's manifest records it")
    version: int = Field(ge=1, description="the reference set's version")
    reference_pose: PoseMsg = Field(description="the reference camera in the bin frame")
    view_pose: PoseMsg = Field(description="this view's camera in the bin frame")
    intrinsics: Intrinsics = Field(description="of the reference image (the same camera takes the view)")
    plane_normal: tuple[FiniteFloat, FiniteFloat, FiniteFloat]
    plane_distance: FiniteFloat = Field(description="m, in the reference camera's optical frame")


class ClassifyRequest(WireMessage):
    """Metadata of a classify request; the encoded image is the query payload."""

    type: Literal["cellctl/ClassifyRequest"] = "cellctl/ClassifyRequest"
    v: Literal[1] = 1
    surface: Surface
    format: Literal["png", "jpeg"] = "png"
    reference: ClassifyReference | None = Field(
        default=None, description="compare with this commissioned reference (None: the detector alone)"
    )


class ClassifyReply(WireMessage):
    type: Literal["cellctl/ClassifyReply"] = "cellctl/ClassifyReply"
    v: Literal[1] = 1
    label: Literal["clean", "dirty"]
    p_dirty: FiniteFloat = Field(ge=0.0, le=1.0)
    uncertain: bool = False
    model_id: str = Field(max_length=256)
    p_supervised: FiniteFloat | None = Field(default=None, ge=0.0, le=1.0, description="supervised part alone")
    anomaly_z: FiniteFloat | None = Field(default=None, description="clean-only part: largest patch distance, clean-σ")
    heatmap: str | None = Field(
        default=None, max_length=8192, description="per-patch p_dirty, base64 of uint8 p·255, row-major heat_grid²"
    )
    heat_grid: int | None = Field(default=None, ge=1, le=64)
    decided_by: Literal["reference", "detector", "model"] | None = Field(
        default=None,
        description="reference: the detector fused with the change map against the stored reference; detector: "
        "the detector alone; model: the whole-image model",
    )
    reference_reason: ReferenceReason | None = Field(
        default=None, description="a request with a reference: aligned, or why the detector decided alone"
    )


class ClassifierModelsRequest(WireMessage):
    """Ask the classifier worker which models it serves (``cell/<id>/classifier/models``)."""

    type: Literal["cellctl/ClassifierModelsRequest"] = "cellctl/ClassifierModelsRequest"
    v: Literal[1] = 1


class ClassifierModel(BaseModel):
    """One surface's model as the worker loaded it at start."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    model_id: str = Field(max_length=256)
    kind: Literal["detector", "enrolled", "supervised"] = Field(
        description="detector: the shipped <surface>.detect.pt; enrolled: classifier.detector_files; "
        "supervised: the whole-image model"
    )
    path: str = Field(max_length=4096)
    threshold: FiniteFloat = Field(ge=0.0, le=1.0)
    enrolled_on: dict[str, Any] | None = Field(
        default=None, description="enrolled: the card's source (folder, sha256, images) and base model id"
    )
    runtime: dict[str, Any] | None = Field(
        default=None,
        description="detectors: what runs the networks — onnx (export file, its sha256, intra-op threads) or torch",
    )


class ClassifierModels(WireMessage):
    """The classifier worker's models per surface, and those it could not load (why)."""

    type: Literal["cellctl/ClassifierModels"] = "cellctl/ClassifierModels"
    v: Literal[1] = 1
    decision: Literal["auto", "detector", "supervised"]
    models: dict[Surface, ClassifierModel] = Field(default_factory=dict)
    problems: dict[str, str] = Field(default_factory=dict)


class EnrollRequest(WireMessage):
    """Enroll one surface's detector from a folder of clean views (``cell/<id>/classifier/enroll``).

    The folder and the file are paths on the classifier worker's host (the reference root is
    shared with the supervisor's host; the default cell runs both on one).
    """

    type: Literal["cellctl/EnrollRequest"] = "cellctl/EnrollRequest"
    v: Literal[1] = 1
    surface: Surface
    images: str = Field(max_length=4096, description="folder of the surface's clean views")
    out: str = Field(max_length=4096, description="the enrolled detector file to write, then use")


class EnrollReply(WireMessage):
    type: Literal["cellctl/EnrollReply"] = "cellctl/EnrollReply"
    v: Literal[1] = 1
    surface: Surface
    model_id: str = Field(max_length=256)
    path: str = Field(max_length=4096)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    threshold: FiniteFloat = Field(ge=0.0, le=1.0)
    images: int = Field(ge=0)
