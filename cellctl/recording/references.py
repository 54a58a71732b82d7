"""Reference sets: one image per planned viewpoint of a bin declared clean, with its camera pose.

A commissioning cycle (Start ``mode=commission``, maintenance unit mode, a named user) writes one;
every later cycle whose plan it holds can compare each view with the same view of the clean bin
(change detection). Layout, beside the plan cache (:func:`reference_root`: the sibling folder
``references/`` of ``planner.plans_dir``, so a plan and its references move together)::

    references/<bin_type>/v0001/manifest.json              the set (complete once this exists)
                               /<surface>/<plan_id>/<viewpoint>.png   the view as the classifier saw it
                               /<surface>.enrolled.pt      the detector enrolled from the surface's views
                         /v0002/…                          a later commissioning: never replaces v0001
                         /.staging-<cycle_id>/             a commissioning cycle's views while it runs

Versions count per bin type (1, 2, …); a set is never rewritten, so the version a cycle names in its
CycleResult stays readable. A lookup takes the newest complete set holding the plan id: a replan
(new plan id) has no references until it is commissioned.

The image is the classifier's input (board masked, for ``classifier.mask_cabin`` surfaces the cabin
filled): what the detector judges is what the change detection compares. The poses are in the robot
base frame: ``T_base_cam`` (the camera where the image was taken, as the robot reported it) and
``T_base_bin`` (the bin pose the plan was adjusted to), so ``T_bin_cam`` is the view relative to
the bin, comparable across parks.

Audit: the manifest's sha256 (and the manifest itself) is written into the commissioning cycle's
MCAP (topic :data:`cellctl.bus.topics.REFERENCES`), whose sha256 the cycle's row of the hash-chained
index holds. :func:`verify_references` checks each set's manifest against that record and each
image and enrolled file against the manifest (``cellctl audit verify`` runs it).

Light module (json, numpy, pydantic): the supervisor imports it.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cellctl.errors import RecordingError
from cellctl.hashing import bytes_sha256, file_sha256, file_sha256_or_none
from cellctl.messages import Intrinsics
from cellctl.surface import Surface

__all__ = [
    "FORMAT",
    "MANIFEST",
    "EnrolledFile",
    "Reference",
    "ReferenceImage",
    "ReferenceManifest",
    "ReferencePlan",
    "ReferenceSetWriter",
    "check_set_files",
    "enrolled_file",
    "latest_set",
    "lookup_reference",
    "read_manifest",
    "reference_in",
    "reference_root",
    "set_files",
    "set_versions",
]

FORMAT = "cellctl-references/1"
MANIFEST = "manifest.json"
_VERSION = re.compile(r"v(\d{4,})")
_SAFE = re.compile(r"[^A-Za-z0-9._-]")


def _safe(name: str) -> str:
    """A bin type or plan id as one folder name (never a path: ``..`` and separators replaced)."""
    s = _SAFE.sub("_", name)
    return "_" + s if s.startswith(".") or not s else s


def _matrix(T: np.ndarray) -> list[list[float]]:
    m = np.asarray(T, dtype=float)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise RecordingError(f"a reference pose must be a finite 4x4 transform, got shape {m.shape}")
    return [[float(x) for x in row] for row in m]


class ReferenceImage(BaseModel):
    """One viewpoint's reference: its image (relative to the set's folder) and where it was taken."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    viewpoint: int = Field(ge=0)
    image: str
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    T_base_cam: list[list[float]] = Field(description="camera pose in the robot base frame, 4x4 (m)")
    T_base_bin: list[list[float]] | None = Field(default=None, description="the bin pose the plan was adjusted to")
    intrinsics: Intrinsics | None = None


class ReferencePlan(BaseModel):
    """The references of one plan (a station's surface in a whole-bin cycle)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    plan_id: str
    surface: Surface
    station: int | None = None
    views: dict[int, ReferenceImage] = Field(default_factory=dict)


class EnrolledFile(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    file: str = Field(description="relative to the set's folder")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    model_id: str


class ReferenceManifest(BaseModel):
    """``manifest.json`` of a reference set (format :data:`FORMAT`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["cellctl-references/1"] = FORMAT
    bin_type: str
    version: int = Field(ge=1)
    cycle_id: str = Field(description="the commissioning cycle (its MCAP records this manifest's sha256)")
    declared_by: str = Field(description="the user who declared the bin clean (the Start command's user)")
    created: str
    whole_plan_id: str | None = None
    plans: dict[str, ReferencePlan] = Field(default_factory=dict)
    enrolled: dict[Surface, EnrolledFile] = Field(default_factory=dict)
    problems: dict[str, str] = Field(default_factory=dict)

    @property
    def references(self) -> int:
        return sum(len(p.views) for p in self.plans.values())


@dataclass(frozen=True)
class Reference:
    """What the scan compares a view with (:func:`lookup_reference`)."""

    image: Path
    T_base_cam: np.ndarray
    """Camera pose in the robot base frame when the reference was taken, shape (4, 4)."""
    T_base_bin: np.ndarray | None
    """The bin pose the reference's plan was adjusted to, shape (4, 4); None if not recorded."""
    intrinsics: Intrinsics | None
    version: int
    bin_type: str
    plan_id: str
    viewpoint: int
    sha256: str

    @property
    def T_bin_cam(self) -> np.ndarray | None:
        """The reference camera in the bin frame: the pose to compare a new view's with across parks."""
        if self.T_base_bin is None:
            return None
        return np.linalg.inv(self.T_base_bin) @ self.T_base_cam


def reference_root(cfg: Any) -> Path:
    """``references/`` beside the plan cache (``planner.plans_dir``), resolved like every config path."""
    return cfg.path(cfg.planner.plans_dir).parent / "references"


def set_versions(root: Path | str, bin_type: str) -> list[tuple[int, Path]]:
    """The complete sets (with a manifest) of ``bin_type``, oldest first: ``[(version, folder)]``."""
    folder = Path(root) / _safe(bin_type)
    out = []
    if folder.is_dir():
        for d in folder.iterdir():
            m = _VERSION.fullmatch(d.name)
            if m and (d / MANIFEST).is_file():
                out.append((int(m.group(1)), d))
    return sorted(out)


def read_manifest(path: Path | str) -> ReferenceManifest:
    """Read and type a set's manifest.

    Raises:
        RecordingError: missing, unreadable, not JSON or not a reference manifest (names the file).
    """
    p = Path(path)
    try:
        return ReferenceManifest.model_validate_json(p.read_bytes())
    except OSError as err:
        raise RecordingError(f"reference manifest {str(p)!r} cannot be read: {err.strerror}") from err
    except ValidationError as err:
        first = err.errors()[0]
        raise RecordingError(
            f"reference manifest {str(p)!r} is not a {FORMAT} manifest: {'.'.join(map(str, first['loc']))}: "
            f"{first['msg']}"
        ) from None


def latest_set(root: Path | str, bin_type: str, plan_id: str) -> tuple[ReferenceManifest, Path] | None:
    """The newest complete set of ``bin_type`` that holds ``plan_id``, with its folder; None if none.

    A set whose manifest cannot be read is skipped (the audit reports it), never fatal to a cycle.
    """
    for _v, folder in reversed(set_versions(root, bin_type)):
        try:
            man = read_manifest(folder / MANIFEST)
        except RecordingError:
            continue
        if plan_id in man.plans:
            return man, folder
    return None


def lookup_reference(root: Path | str, bin_type: str, plan_id: str, viewpoint: int) -> Reference | None:
    """The reference image and camera pose of one planned viewpoint, from the newest set holding the plan.

    Args:
        root: :func:`reference_root` of the cell's config.
        bin_type, plan_id: the plan the cycle scans (``PlanLookupReply.plan_id``).
        viewpoint: the viewpoint's ``index`` in that plan.

    Returns:
        None when no set holds the plan (not commissioned, or a replan since) or the set has no
        reference for that viewpoint (it was refused during commissioning).
    """
    return reference_in(latest_set(root, bin_type, plan_id), plan_id, viewpoint)


def reference_in(found: tuple[ReferenceManifest, Path] | None, plan_id: str, viewpoint: int) -> Reference | None:
    """The reference of one planned viewpoint in a set :func:`latest_set` found (a cycle resolves the set
    once per plan and looks its views up here); None when there is no set or it has no such view."""
    if found is None:
        return None
    man, folder = found
    view = man.plans[plan_id].views.get(viewpoint)
    if view is None:
        return None
    bin_pose = np.array(view.T_base_bin) if view.T_base_bin is not None else None
    return Reference(
        image=folder / view.image,
        T_base_cam=np.array(view.T_base_cam),
        T_base_bin=bin_pose,
        intrinsics=view.intrinsics,
        version=man.version,
        bin_type=man.bin_type,
        plan_id=plan_id,
        viewpoint=viewpoint,
        sha256=view.sha256,
    )


class ReferenceSetWriter:
    """A commissioning cycle's reference set while it is built: views go into a staging folder,
    :meth:`claim` gives it the next version, :meth:`finish` writes its manifest (the set exists from then on).

    Args:
        root: :func:`reference_root`.
        bin_type: the identified bin type.
        cycle_id: the commissioning cycle (names the staging folder).
    """

    def __init__(self, root: Path | str, bin_type: str, cycle_id: str) -> None:
        self.root = Path(root)
        self.bin_type = bin_type
        self.cycle_id = cycle_id
        self.folder = self.root / _safe(bin_type) / f".staging-{_safe(cycle_id)}"
        self.version: int | None = None
        self.plans: dict[str, ReferencePlan] = {}

    def add(
        self,
        plan_id: str,
        surface: str,
        station: int | None,
        viewpoint: int,
        image: bytes,
        fmt: str,
        T_base_cam: np.ndarray,
        T_base_bin: np.ndarray | None,
        intrinsics: Intrinsics | None,
    ) -> Path:
        """Store one view as its viewpoint's reference (a re-taken view replaces the earlier one).

        Raises:
            RecordingError: the set is already claimed, a pose is not a 4x4 transform, or the file
                cannot be written.
        """
        if self.version is not None:
            raise RecordingError(f"reference set v{self.version} of {self.bin_type!r} is closed; cannot add to it")
        ext = "jpg" if fmt == "jpeg" else "png"
        rel = Path(surface) / _safe(plan_id) / f"{viewpoint:04d}.{ext}"
        path = self.folder / rel
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(image)
        except OSError as err:
            raise RecordingError(f"cannot write reference image {str(path)!r}: {err.strerror}") from err
        view = ReferenceImage(
            viewpoint=viewpoint,
            image=rel.as_posix(),
            sha256=bytes_sha256(image),
            T_base_cam=_matrix(T_base_cam),
            T_base_bin=_matrix(T_base_bin) if T_base_bin is not None else None,
            intrinsics=intrinsics,
        )
        old = self.plans.get(plan_id) or ReferencePlan(plan_id=plan_id, surface=surface, station=station)  # type: ignore[arg-type]
        if old.surface != surface:
            raise RecordingError(f"plan {plan_id!r} was stored as {old.surface!r}, now given as {surface!r}")
        self.plans[plan_id] = old.model_copy(update={"views": {**old.views, viewpoint: view}})
        return path

    def surfaces(self) -> list[str]:
        """The surfaces with at least one reference, in the order they were first stored."""
        return list(dict.fromkeys(p.surface for p in self.plans.values()))

    def claim(self) -> Path:
        """Give the staged views the next version of the bin type (rename; the set has no manifest yet,
        so no lookup sees it). Returns the set's folder; enrolled files go into it before :meth:`finish`.

        Raises:
            RecordingError: nothing staged, or the folder cannot be renamed.
        """
        if self.version is not None:
            return self.folder
        if not self.plans:
            raise RecordingError(f"commissioning cycle {self.cycle_id!r} stored no reference view; nothing to claim")
        parent = self.folder.parent
        taken = [int(m.group(1)) for d in parent.iterdir() if (m := _VERSION.fullmatch(d.name))]
        v = max(taken, default=0) + 1
        for _ in range(100):  # another cell sharing the plan cache may claim the same number first
            target = parent / f"v{v:04d}"
            try:
                target.mkdir()  # atomic claim of the number; the rename then fills the empty folder
                os.replace(self.folder, target)
            except FileExistsError:
                v += 1
                continue
            except OSError as err:
                raise RecordingError(
                    f"cannot move reference set {str(self.folder)!r} to {str(target)!r}: {err}"
                ) from err
            self.folder, self.version = target, v
            return target
        raise RecordingError(f"no free reference set version under {str(parent)!r} after v{v:04d}")

    def finish(
        self,
        declared_by: str,
        whole_plan_id: str | None,
        enrolled: dict[str, EnrolledFile],
        problems: dict[str, str],
    ) -> tuple[ReferenceManifest, Path, str]:
        """Write the manifest (atomically): the set is complete. Returns (manifest, its path, its sha256).

        Raises:
            RecordingError: the manifest cannot be written.
        """
        folder = self.claim()
        assert self.version is not None
        man = ReferenceManifest(
            bin_type=self.bin_type,
            version=self.version,
            cycle_id=self.cycle_id,
            declared_by=declared_by,
            created=_dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds"),
            whole_plan_id=whole_plan_id,
            plans=self.plans,
            enrolled=enrolled,  # type: ignore[arg-type]
            problems=problems,
        )
        data = json.dumps(man.model_dump(mode="json"), indent=1, sort_keys=True).encode()
        path = folder / MANIFEST
        try:
            fd, tmp = tempfile.mkstemp(prefix=".manifest.", suffix=".tmp", dir=folder)
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.chmod(tmp, 0o644)
            os.replace(tmp, path)
        except OSError as err:
            raise RecordingError(f"cannot write reference manifest {str(path)!r}: {err}") from err
        return man, path, bytes_sha256(data)

    def discard(self) -> None:
        """Drop an unclaimed staging folder (a commissioning cycle that ended before its set was claimed)."""
        if self.version is None:
            shutil.rmtree(self.folder, ignore_errors=True)


def enrolled_file(folder: Path, surface: str, model_id: str) -> EnrolledFile | None:
    """The manifest entry of ``<surface>.enrolled.pt`` in a claimed set's folder, None if it is missing."""
    rel = f"{surface}.enrolled.pt"
    sha = file_sha256_or_none(folder / rel)
    return EnrolledFile(file=rel, sha256=sha, model_id=model_id) if sha is not None else None


def set_files(folder: Path, man: ReferenceManifest) -> list[tuple[str, str]]:
    """Every file a manifest vouches for: ``[(relative path, sha256)]``."""
    out = [(v.image, v.sha256) for p in man.plans.values() for v in p.views.values()]
    return out + [(e.file, e.sha256) for e in man.enrolled.values()]


def check_set_files(folder: Path, man: ReferenceManifest) -> list[str]:
    """What differs between a set's files and its manifest (one line each; empty: intact)."""
    bad = []
    for rel, sha in set_files(folder, man):
        p = folder / rel
        found = file_sha256(p) if p.is_file() else None
        if found is None:
            bad.append(f"{p} is missing; the manifest expects sha256 {sha}")
        elif found != sha:
            bad.append(f"{p} has sha256 {found}, the manifest expects {sha}: edited or replaced")
    return bad
