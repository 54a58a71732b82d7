"""The commissioning cycle over real Zenoh (issue 34, item 1): Start ``mode=commission`` in maintenance
by a named user writes one reference per viewpoint with its camera pose, enrolls the detectors through
the classifier worker, chains the set into the audit; later cycles say what they were judged against.

Worker doubles (single-station plan of three viewpoints); the classifier double's ``enroll`` writes a
small file and then answers with an enrolled model id, like the real worker does after enrolling.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader

from cellctl.bus import topics
from cellctl.hashing import bytes_sha256
from cellctl.messages import (
    ClassifyReply,
    ClassifyRequest,
    Command,
    EnrollReply,
    EnrollRequest,
    PlanLookupReply,
    PlanLookupRequest,
    now_iso,
)
from cellctl.recording.audit import FindingKind, verify_audit
from cellctl.recording.references import MANIFEST, lookup_reference, read_manifest, reference_root, set_versions
from tests.fakes.workers import CAM_POSE, INTRINSICS, FakeCell
from tests.supervisor.test_cycle_over_zenoh import cell, plc  # noqa: F401 - the daemon and PLC fixtures
from tests.supervisor.test_station_loop import faces as faces  # the case-study faces per surface

USER = "hmi:alice"


class CommissionCell(FakeCell):
    """Doubles with a classifier that enrolls (a stand-in file) and a planner whose plan id can change."""

    def __init__(self, cfg, **kw) -> None:
        super().__init__(cfg, **kw)
        self.plan_id = "plan-1"
        self.enrolled: dict[str, str] = {}
        self.enroll_requests: list[EnrollRequest] = []

    def start(self) -> CommissionCell:
        super().start()
        self.servers["classifier"].serve("enroll", EnrollRequest, self._enroll)
        return self

    def _enroll(self, req: EnrollRequest, _: bytes | None) -> EnrollReply:
        self.enroll_requests.append(req)
        self._guard("enroll")  # fail={"enroll": why}: refused as the real worker refuses too few views
        data = f"enrolled {req.surface} from {req.images}".encode()
        with open(req.out, "wb") as f:
            f.write(data)
        self.enrolled[req.surface] = f"{req.surface}-enrolled-{bytes_sha256(data)[:12]}"
        return EnrollReply(
            surface=req.surface,
            model_id=self.enrolled[req.surface],
            path=req.out,
            sha256=bytes_sha256(data),
            threshold=0.5,
            images=3,
        )

    def _classify(self, req: ClassifyRequest, image: bytes | None) -> ClassifyReply:
        r = super()._classify(req, image)
        return r.model_copy(update={"model_id": self.enrolled.get(req.surface, f"{req.surface}-detect-000000000000")})

    def _lookup(self, req: PlanLookupRequest, p: bytes | None) -> PlanLookupReply:
        r = super()._lookup(req, p)
        return r.model_copy(update={"plan_id": self.plan_id}) if r.hit else r


def _start(plc, mode: str | None = None, user: str | None = USER):  # noqa: F811
    params = {"mode": mode} if mode else {}
    return plc.send(Command(command="start", user=user, params=params, request_id=plc.next_id(), stamp=now_iso()))


def _cycle(plc, mode: str | None = None, user: str | None = USER, timeout: float = 30):  # noqa: F811
    plc.drain()
    plc.cmd("reset")
    plc.wait_state("Idle")
    ack = _start(plc, mode, user)
    assert ack.accepted, ack.reason
    plc.wait_state("Complete", timeout)
    return plc.results.get(timeout=10)


def _to_maintenance(plc) -> None:  # noqa: F811
    if plc.cmd("reset").accepted:  # from Complete (a unit mode changes only at rest)
        plc.wait_state("Idle")
    ack = plc.unit_mode("maintenance", user=USER)
    assert ack.accepted, ack.reason


def test_commission_is_refused_in_production_and_without_a_user(cfg, cell, plc) -> None:  # noqa: F811
    with CommissionCell(cfg) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        ack = _start(plc, "commission")
        assert not ack.accepted and ack.state == "Idle"
        assert "'commission'" in ack.reason and "'production'" in ack.reason and "maintenance" in ack.reason
        _to_maintenance(plc)
        nobody = _start(plc, "commission", user=None)
        assert not nobody.accepted and "user" in nobody.reason
        assert plc.wait_state("Idle").state == "Idle"
    assert "move" not in fake.calls and not fake.enroll_requests
    assert not reference_root(cfg).exists()


def test_commissioning_writes_a_reference_set_chained_into_the_audit(cfg, cell, plc) -> None:  # noqa: F811
    root = reference_root(cfg)
    with CommissionCell(cfg) as fake:
        shipped = _cycle(plc)  # production: an ordinary cycle, nothing commissioned yet
        _to_maintenance(plc)
        res = _cycle(plc, "commission")
        after = _cycle(plc)
    assert shipped.decision_path == {"external": "shipped"} and shipped.reference_version is None
    assert res.outcome == "completed", res.reason
    c = res.commission
    assert c is not None and c.version == 1 and c.references == 3 and c.declared_by == USER
    assert c.bin_type == "case_study" and c.plan_ids == ["plan-1"] and not c.problems
    # the commissioning cycle's own views were judged before its set existed
    assert res.decision_path == {"external": "shipped"}
    # one enrollment per surface, from the set's own views, into the set's folder
    (req,) = fake.enroll_requests
    folder = root / "case_study" / "v0001"
    assert req.surface == "external" and req.images == str(folder / "external")
    assert c.enrolled == {"external": str(folder / "external.enrolled.pt")}
    man = read_manifest(folder / MANIFEST)
    assert man.cycle_id == res.cycle_id and man.declared_by == USER and man.version == 1
    assert sorted(man.plans["plan-1"].views) == [0, 1, 2]
    for k in range(3):
        ref = lookup_reference(root, "case_study", "plan-1", k)
        assert ref is not None and ref.image.is_file() and ref.version == 1
        assert bytes_sha256(ref.image.read_bytes()) == ref.sha256
        np.testing.assert_allclose(ref.T_base_cam, CAM_POSE.matrix())
        assert ref.intrinsics == INTRINSICS and ref.T_bin_cam is not None
    assert lookup_reference(root, "case_study", "plan-1", 3) is None
    assert lookup_reference(root, "case_study", "plan-2", 0) is None
    # the MCAP holds the manifest's sha256; the index row chains the MCAP; the audit checks the set
    with open(cfg.path(res.log), "rb") as f:
        recs = [json.loads(m.data) for _s, _c, m in make_reader(f).iter_messages(topics=[topics.REFERENCES])]
    assert recs[-1]["manifest_sha256"] == c.manifest_sha256 == bytes_sha256((folder / MANIFEST).read_bytes())
    index, logs = cfg.path(cfg.recording.index), cfg.path(cfg.recording.dir)
    report = verify_audit(index, logs, references=root)
    assert report.ok, [f.message for f in report.findings]
    # a later cycle of the commissioned plan is judged against the references
    assert after.outcome == "completed" and after.decision_path == {"external": "references"}
    assert after.reference_version == 1
    # per view: the request carried the viewpoint's reference (bin-frame poses, the plane) and the reply's path
    assert [(v.decided_by, v.reference_reason) for v in after.viewpoints] == [("reference", "aligned")] * 3
    assert [v.decided_by for v in res.viewpoints] == [None] * 3  # the commissioning views: no reference sent
    with open(cfg.path(after.log), "rb") as f:  # in the log's own metadata and in Status.admin too
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["result"]
    assert meta["decision_path"] == "external=references" and meta["reference_version"] == "1"
    last = plc.wait_for(lambda s: s.admin.last_cycle and s.admin.last_cycle.cycle_id == after.cycle_id, 5)
    assert last is not None and last.admin.last_cycle.decision_path == {"external": "references"}
    # the audit notices an edited reference image and an edited manifest
    ref0 = lookup_reference(root, "case_study", "plan-1", 0)
    assert ref0 is not None
    ref0.image.write_bytes(ref0.image.read_bytes() + b"x")
    (folder / MANIFEST).write_text((folder / MANIFEST).read_text().replace(USER, "hmi:mallory"))
    kinds = [f.kind for f in verify_audit(index, logs, references=root).findings]
    assert kinds.count(FindingKind.reference_mismatch) == 2, kinds


def test_a_replanned_bin_falls_back_until_commissioned_again(cfg, cell, plc) -> None:  # noqa: F811
    root = reference_root(cfg)
    with CommissionCell(cfg) as fake:
        _to_maintenance(plc)
        first = _cycle(plc, "commission")
        fake.plan_id = "plan-2"  # the bin stood somewhere new: the planner made a new plan
        replanned = _cycle(plc)
        again = _cycle(plc, "commission")
        fake.plan_id = "plan-1"  # the first plan's set is still there (sets are never rewritten)
        old_plan = _cycle(plc)
    assert first.commission is not None and first.commission.version == 1
    # no references for the new plan: the detector enrolled at commissioning decides, and says so
    assert replanned.decision_path == {"external": "enrolled"} and replanned.reference_version is None
    assert [v.reference_reason for v in replanned.viewpoints] == [None] * 3  # no set holds plan-2
    assert again.commission is not None and again.commission.version == 2 and again.commission.plan_ids == ["plan-2"]
    assert [v for v, _ in set_versions(root, "case_study")] == [1, 2]
    assert old_plan.decision_path == {"external": "references"} and old_plan.reference_version == 1
    assert lookup_reference(root, "case_study", "plan-2", 1).version == 2


def test_a_surface_that_cannot_be_enrolled_keeps_its_references_and_says_why(cfg, cell, plc) -> None:  # noqa: F811
    with CommissionCell(cfg, fail={"enroll": "3 images; enrollment needs at least 10 clean images"}):
        _to_maintenance(plc)
        res = _cycle(plc, "commission")
    assert res.outcome == "completed", res.reason
    c = res.commission
    assert c is not None and c.references == 3 and c.enrolled == {}
    assert "at least 10" in c.problems["external"]
    man = read_manifest(reference_root(cfg) / "case_study" / "v0001" / MANIFEST)
    assert man.enrolled == {} and "external" in man.problems


class TestWholeBin:
    """The shipped default: a whole-bin cycle, three stations, both surfaces (the doubles of test_station_loop)."""

    @pytest.fixture
    def cfg(self, tmp_path, port):  # the shipped config on a private port and folders
        from cellctl.config import load_config
        from tests.conftest import cfg_overrides
        from tests.supervisor.test_whole_default import PINS

        return load_config(None, [o for o in cfg_overrides(tmp_path, port) if not o.startswith(PINS)])

    def test_a_whole_bin_commissioning_references_every_station_plan(self, cfg, cell, plc, faces) -> None:  # noqa: F811
        from tests.supervisor.test_whole_default import WideWholeFakeCell

        class WholeCommissionCell(CommissionCell, WideWholeFakeCell):
            _lookup = WideWholeFakeCell._lookup

        assert cfg.planner.whole.enabled
        with WholeCommissionCell(cfg, faces=faces) as fake:
            _to_maintenance(plc)
            res = _cycle(plc, "commission", timeout=60)
            after = _cycle(plc, timeout=60)
        assert res.outcome == "completed", res.reason
        c = res.commission
        plans = ["st0-external", "st0-internal", "st1-external", "st1-internal", "st2-external"]
        assert c is not None and c.plan_ids == plans and c.references == 10 and not c.problems
        assert sorted(r.surface for r in fake.enroll_requests) == ["external", "internal"]
        assert sorted(c.enrolled) == ["external", "internal"]
        man = read_manifest(reference_root(cfg) / "case_study" / "v0001" / MANIFEST)
        assert man.whole_plan_id == "whole-1" and man.plans["st1-internal"].station == 1
        assert res.decision_path == {"external": "shipped", "internal": "shipped"}
        assert after.decision_path == {"external": "references", "internal": "references"}
        assert after.verdict == "clean" and after.reference_version == 1


def test_replay_verify_of_commissioning_adds_no_set(cfg, cell, plc, tmp_path) -> None:  # noqa: F811
    from cellctl.geometry.catalog import load_catalog
    from cellctl.recording.replay import verify
    from tests.fakes.workers import fake_identify
    from tests.supervisor.test_cycle_over_zenoh import _verify_config

    with CommissionCell(cfg):
        _to_maintenance(plc)
        res = _cycle(plc, "commission")
        after = _cycle(plc)
    assert after.decision_path == {"external": "references"}
    catalog = load_catalog(cfg.path(cfg.catalog))
    for r in (res, after):
        vcfg = _verify_config(tmp_path / f"v{r.cycle_id}", settle_s=0)
        # the cell's own plan cache: the replay must still write no set beside it
        vcfg = vcfg.model_copy(update={"planner": vcfg.planner.model_copy(update={"plans_dir": cfg.planner.plans_dir})})
        report = verify(cfg.path(r.log), vcfg, timeout_s=30, identification=(fake_identify, catalog))
        assert report.ok, report.differences
    # the replayed commissioning wrote its set into a scratch folder, never beside the cell's plan cache
    assert [v for v, _ in set_versions(reference_root(cfg), "case_study")] == [1]


class TestReferencesOff:
    """``classifier.references: false``: a commissioned plan's views go without their references."""

    @pytest.fixture
    def cfg(self, tmp_path, port):
        from cellctl.config import load_config
        from tests.conftest import cfg_overrides

        return load_config(None, [*cfg_overrides(tmp_path, port), "classifier.references=false"])

    def test_views_are_judged_by_the_detector_alone(self, cfg, cell, plc) -> None:  # noqa: F811
        with CommissionCell(cfg):
            _to_maintenance(plc)
            res = _cycle(plc, "commission")
            after = _cycle(plc)
        assert res.commission is not None and res.commission.references == 3
        assert after.decision_path == {"external": "enrolled"} and after.reference_version is None
        assert [(v.decided_by, v.reference_reason) for v in after.viewpoints] == [(None, None)] * 3
