"""One definition per concept (issue 18): a second definition anywhere in the package fails here."""

from __future__ import annotations

import re

import pytest

from cellctl.config import project_root

ROOT = project_root() / "cellctl"

# concept → (regex of a definition, the one module allowed to hold it)
CONCEPTS = {
    "BoardSpec": (r"^class BoardSpec\b", "geometry/catalog.py"),
    "look_at": (r"^def look_at\(", "geometry/transforms.py"),
    "decode_image": (r"^\s*def decode_image\(", "images.py"),
    "encode_image": (r"^\s*def encode_image\(", "images.py"),
    "MAX_IMAGE_BYTES": (r"^\s*MAX_IMAGE_BYTES\s*=", "images.py"),
    "file hashing": (r"^\s*def (file_sha256|sha256_file)\w*\(", "hashing.py"),
    "CameraModel": (r"^class CameraModel\b", "geometry/camera.py"),
    "surface list": (r"^\s*SURFACES\s*[:=]", "surface.py"),
    "surface name type": (r"^Surface\s*=", "surface.py"),
    "face tags": (r"^(EXTERNAL|INTERNAL)\s*=", "surface.py"),
    # a fault-injection case's result is FaultCaseResult
    "FaultReport": (r"^class FaultReport\b", "messages/status.py"),
    # a config record that rejects unknown keys (was four private ``_Model`` copies)
    "strict config model base": (r"^class (_Model|\w*ConfigModel)\(BaseModel\)", "strict_model.py"),
    # a client of the cell's PLC command/status contract (was three: bus, gateway, HMI; CellLink twice)
    "PLC contract client": (r"^class (CellLink|\w*PlcClient|\w*ContractClient|RequestIds)\b", "bus/plc_client.py"),
}


def _definitions(pattern: str) -> list[str]:
    rx = re.compile(pattern, re.MULTILINE)
    hits = []
    for path in sorted(ROOT.rglob("*.py")):
        for m in rx.finditer(path.read_text(encoding="utf-8")):
            hits.append(str(path.relative_to(ROOT)) + ":" + m.group(0).strip())
    return hits


@pytest.mark.parametrize("concept", sorted(CONCEPTS))
def test_one_definition(concept: str) -> None:
    pattern, home = CONCEPTS[concept]
    hits = _definitions(pattern)
    assert hits and all(h.startswith(home + ":") for h in hits), f"{concept}: expected only in {home}, found {hits}"


def test_no_focal_length_literal_outside_the_camera_model() -> None:
    """The D435's 920 px (and the old 910 px) live in geometry/camera.py only."""
    rx = re.compile(r"\b9[12]0\.0\b|\b9[12]0\.0?\s*/\s*1280")
    hits = [
        f"{p.relative_to(ROOT)}:{i}"
        for p in sorted(ROOT.rglob("*.py"))
        if p.name != "camera.py" or p.parent.name != "geometry"
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if rx.search(line)
    ]
    assert hits == []


def test_no_inline_surface_list() -> None:
    """The surface names as a list/tuple/choices are spelt only in cellctl/surface.py."""
    rx = re.compile(r"""["']external["']\s*,\s*["']internal["']""")
    hits = [
        f"{p.relative_to(ROOT)}:{i}"
        for p in sorted(ROOT.rglob("*.py"))
        if p.name != "surface.py"
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
        if rx.search(line)
    ]
    assert hits == []
