"""The classifier worker judges a view against its commissioned reference when the request carries one
(issue 34): the shipped detector and fitted fusion decide, the reply says so; a reference it cannot
use (altered file, pose past the mirror tolerance, no fusion) leaves the detector in use alone, and
the reply says why."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellctl.classify.contamination import closeup_steel
from cellctl.hashing import bytes_sha256
from cellctl.images import encode_image
from cellctl.messages import ClassifyReference, ClassifyRequest, Intrinsics, PoseMsg
from cellctl.workers.classifier import ClassifierService

SHIPPED = Path(__file__).resolve().parents[2] / "models" / "classifier"


@pytest.fixture(scope="module")
def service() -> ClassifierService:
    return ClassifierService(SHIPPED, threads=1, decision="detector", runtime="torch")


def _view(tmp_path: Path, surface: str) -> tuple[bytes, Path]:
    rgb = (closeup_steel(surface, 256, 144, np.random.default_rng(3)) * 255).astype(np.uint8)
    png = encode_image(rgb, "png")
    path = tmp_path / f"{surface}.png"
    path.write_bytes(png)
    return png, path


def _reference(path: Path, offset_m: float = 0.0) -> ClassifyReference:
    T = np.eye(4)
    T[:3, 3] = (0.0, 0.0, -0.3)  # 0.3 m in front of the wall z = 0, looking along +z
    T2 = T.copy()
    T2[0, 3] += offset_m
    return ClassifyReference(
        image=str(path),
        sha256=bytes_sha256(path.read_bytes()),
        version=1,
        reference_pose=PoseMsg.from_matrix(T, "bin"),
        view_pose=PoseMsg.from_matrix(T2, "bin"),
        intrinsics=Intrinsics(width=256, height=144, fx=200.0, fy=200.0, cx=127.5, cy=71.5),
        plane_normal=(0.0, 0.0, 1.0),
        plane_distance=0.3,
    )


def test_a_view_with_its_reference_is_decided_by_the_comparison(service: ClassifierService, tmp_path: Path) -> None:
    assert sorted(service.references.fusions) == ["external", "internal"], service.references.problems
    png, path = _view(tmp_path, "external")
    ref = _reference(path)
    with_ref, alone = service.classify(
        [(ClassifyRequest(surface="external", reference=ref), png), (ClassifyRequest(surface="external"), png)]
    )
    assert (with_ref.decided_by, with_ref.reference_reason) == ("reference", "aligned")
    assert with_ref.label == "clean" and with_ref.heat_grid == 16
    assert (alone.decided_by, alone.reference_reason) == ("detector", None)


def test_an_unusable_reference_leaves_the_detector_alone_and_says_why(
    service: ClassifierService, tmp_path: Path
) -> None:
    png, path = _view(tmp_path, "internal")
    moved = _reference(path, offset_m=0.02)  # 20 mm: past the polished steel's 7.5 mm tolerance
    altered = _reference(path).model_copy(update={"sha256": "0" * 64})
    far, bad = service.classify(
        [
            (ClassifyRequest(surface="internal", reference=moved), png),
            (ClassifyRequest(surface="internal", reference=altered), png),
        ]
    )
    assert (far.decided_by, far.reference_reason) == ("detector", "out_of_tolerance")
    assert (bad.decided_by, bad.reference_reason) == ("detector", "unreadable")
