"""The daemon over real Zenoh on loopback, driven like a PLC, with worker doubles."""

from __future__ import annotations

import json
import queue
import time

import pytest
from mcap.reader import make_reader

from cellctl.app import build_cell
from cellctl.bus import keys
from cellctl.bus.codec import decode_as
from cellctl.bus.plc_client import PlcClient
from cellctl.messages import Ack, Status
from tests.fakes.workers import FakeCell, fake_identify


class Plc(PlcClient):
    """The shipped PLC client with the short names these tests read best with."""

    def __init__(self, cfg) -> None:
        super().__init__(cfg, "t")
        self.s = self.session
        self.status = self.statuses
        time.sleep(0.2)

    def cmd(self, command: str, **params) -> Ack:
        return self.command(command, timeout=5, **params)

    def wait_state(self, state: str, timeout: float = 10.0) -> Status:
        st = self.wait_for(lambda s: s.state == state, timeout)
        if st is None:
            raise AssertionError(f"state {state!r} not reached in {timeout} s")
        return st


@pytest.fixture
def cell(cfg):
    from cellctl.geometry.catalog import load_catalog

    c = build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    yield c
    c.close()


@pytest.fixture
def plc(cfg, cell):
    p = Plc(cfg)
    yield p
    p.close()


def test_daemon_starts_in_stopped_and_runs_a_full_cycle(cfg, cell, plc) -> None:
    assert cell.supervisor.top_state == "Stopped"
    with FakeCell(cfg, dirty_viewpoints={1}) as fake:
        assert plc.cmd("reset").accepted
        plc.wait_state("Idle")
        ack = plc.cmd("start")
        assert ack.accepted and ack.state == "Starting"
        plc.wait_state("Complete")
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed"
    assert res.verdict == "dirty"
    assert [v.label for v in res.viewpoints] == ["clean", "dirty", "clean"]
    assert res.bin.type == "case_study"
    assert res.dirt_map["seen_dirty"] == [2, 3]
    assert 0 < res.coverage < 0.01  # six small faces of the real case-study mesh
    assert fake.calls.count("move") == 3
    # the cycle's MCAP reads back with the independent reader and holds the whole story
    path = cfg.path(res.log)
    with open(path, "rb") as f:
        reader = make_reader(f)
        topics = [ch.topic for _, ch, _ in reader.iter_messages()]
        schemas = {sc.name for sc, _, _ in reader.iter_messages()}
    assert keys.cmd(cfg.cell_id) in topics and keys.cmd_ack(cfg.cell_id) in topics
    assert f"{keys.robot_op(cfg.cell_id, 'move')}/request" in topics
    assert keys.result(cfg.cell_id) in topics
    assert {
        "foxglove.Log",
        "foxglove.CompressedImage",
        "foxglove.PoseInFrame",
        "foxglove.SceneUpdate",
        "cellctl/Status",
    } <= schemas
    import jsonschema

    with open(path, "rb") as f:
        for schema, _, message in make_reader(f).iter_messages():
            if schema.name.startswith("foxglove."):
                jsonschema.validate(json.loads(message.data), json.loads(schema.data))
    row = cell.index.get(res.cycle_id)
    assert row is not None and row.outcome == "completed" and row.log_sha256


def test_plan_miss_ends_with_replan_required(cfg, cell, plc) -> None:
    with FakeCell(cfg, plan_hit=False) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        plc.wait_state("Complete")
        res = plc.results.get(timeout=5)
    assert res.outcome == "replan_required"
    assert res.planner_job_id == "job-1"
    assert "move" not in fake.calls


def test_no_workers_aborts_with_reason_then_clear_reset_recover(cfg, cell, plc) -> None:
    plc.cmd("reset")
    plc.wait_state("Idle")
    plc.cmd("start")
    st = plc.wait_state("Aborted")
    assert "no robot" in st.last_error
    res = plc.results.get(timeout=5)
    assert res.outcome == "failed" and "no robot" in res.reason
    assert plc.cmd("clear").accepted
    plc.wait_state("Stopped")
    assert plc.cmd("reset").accepted
    st = plc.wait_state("Idle")
    assert st.last_error is None


def test_worker_error_aborts_the_cycle(cfg, cell, plc) -> None:
    with FakeCell(cfg, fail={"approach": "base cannot park: obstacle at 0.3 m"}):
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        st = plc.wait_state("Aborted")
    assert "obstacle at 0.3 m" in st.last_error


def test_hung_worker_times_out_and_aborts(cfg, cell, plc) -> None:
    cell.cfg.supervisor.timeouts.approach = 0.5
    with FakeCell(cfg, hang={"approach"}):
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        st = plc.wait_state("Aborted")
    assert "did not answer" in st.last_error


def test_lost_worker_during_execute_aborts_and_stops_robot(cfg, cell, plc) -> None:
    with FakeCell(cfg, n_viewpoints=20, move_delay_s=0.2) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        deadline = time.monotonic() + 10
        while "move" not in fake.calls and time.monotonic() < deadline:
            time.sleep(0.05)
        t0 = time.monotonic()
        fake.kill("camera")
        st = plc.wait_state("Aborted")
        detect = time.monotonic() - t0
        moves_at_abort = fake.calls.count("move")
        time.sleep(0.5)
        assert fake.calls.count("move") <= moves_at_abort + 1  # at most the in-flight move
        assert fake.stops >= 1
    assert "camera worker lost" in st.last_error
    assert detect < 2.0


def test_hold_and_unhold_resume_the_saved_step(cfg, cell, plc) -> None:
    with FakeCell(cfg, n_viewpoints=6, move_delay_s=0.15) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        deadline = time.monotonic() + 10
        while fake.calls.count("move") < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert plc.cmd("hold").accepted
        plc.wait_state("Held")
        assert plc.cmd("unhold").accepted
        plc.wait_state("Complete")
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed"
    assert sorted(v.index for v in res.viewpoints) == list(range(6))


@pytest.mark.parametrize(
    "payload, reason",
    [
        (b"{not json", "not valid JSON"),
        (b"[1, 2]", "must be a JSON object"),
        (json.dumps({"type": "cellctl/Command", "v": 1, "command": "jump"}).encode(), "command"),
        (json.dumps({"type": "cellctl/Command", "v": 1, "cntrl_cmd": 42}).encode(), "cntrl_cmd 42 is unknown"),
        (json.dumps({"type": "cellctl/Command", "v": 2, "command": "reset"}).encode(), "version 2"),
        (json.dumps({"type": "cellctl/Status", "v": 1}).encode(), "expected a cellctl/Command"),
        (b"x" * 70000, "exceeds the limit"),
        (json.dumps({"type": "cellctl/Command", "v": 1, "command": "hold"}).encode(), "not allowed in state 'Stopped'"),
    ],
)
def test_bad_commands_get_a_rejecting_ack_and_change_nothing(cfg, cell, plc, payload, reason) -> None:
    (reply,) = list(plc.s.get(keys.cmd(cfg.cell_id), payload=payload, timeout=5))
    ack = decode_as(Ack, reply.ok.payload.to_bytes())
    assert not ack.accepted
    assert reason in ack.reason
    assert ack.state == "Stopped" and cell.supervisor.state == "Stopped"


def test_put_commands_are_acked_on_the_ack_key(cfg, cell, plc) -> None:
    acks: queue.Queue[Ack] = queue.Queue()
    plc.s.declare_subscriber(keys.cmd_ack(cfg.cell_id), lambda x: acks.put(decode_as(Ack, x.payload.to_bytes())))
    time.sleep(0.2)
    plc.s.put(
        keys.cmd(cfg.cell_id), json.dumps({"type": "cellctl/Command", "v": 1, "cntrl_cmd": 1, "request_id": "p1"})
    )
    ack = acks.get(timeout=5)
    assert ack.accepted and ack.request_id == "p1" and ack.command == "reset"
    plc.s.put(keys.cmd(cfg.cell_id), b"garbage")
    ack = acks.get(timeout=5)
    assert not ack.accepted and ack.request_id is None


def test_start_params_are_validated(cfg, cell, plc) -> None:
    plc.cmd("reset")
    plc.wait_state("Idle")
    ack = plc.cmd("start", mode="collect")
    assert not ack.accepted and "label" in ack.reason
    ack = plc.cmd("start", speed=3)
    assert not ack.accepted and "speed" in ack.reason
    for where in ("/etc", "../../x", "a/b", ".hidden", ""):  # the PLC names a dataset, never a path
        ack = plc.cmd("start", mode="collect", label="clean", dataset=where)
        assert not ack.accepted and "dataset name" in ack.reason, where
    assert cell.supervisor.state == "Idle"


def _verify_config(out, settle_s: float):
    """A replay supervisor's config: its own private bus and index under ``out``."""
    from cellctl.config import load_config
    from tests.conftest import free_port

    ep = f'["tcp/127.0.0.1:{free_port()}"]'
    return load_config(
        None,
        [
            f"bus.listen={ep}",
            f"bus.connect={ep}",
            f"recording.dir={out}",
            f"recording.index={out / 'cells.db'}",
            f"robot.settle_s={settle_s}",
        ],
    )


def test_replay_verify_passes_on_a_recorded_cycle_and_catches_a_change(cfg, cell, plc, tmp_path) -> None:
    from cellctl.recording.replay import read_cycle, verify

    cell.catalog_for_tests = cell.supervisor.catalog
    with FakeCell(cfg, dirty_viewpoints={2}):
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        plc.wait_state("Complete")
        res = plc.results.get(timeout=5)
    path = cfg.path(res.log)
    assert not read_cycle(path).truncated
    vcfg = _verify_config(tmp_path / "v", settle_s=0)
    report = verify(path, vcfg, timeout_s=30, identification=(fake_identify, cell.catalog_for_tests))
    assert report.ok, report.differences
    assert report.states_replayed[:2] == ["Starting", "Execute.approaching"]
    # the same log checked by a supervisor with another settle time: the move requests differ
    vcfg2 = _verify_config(tmp_path / "w", settle_s=0.5)
    report = verify(path, vcfg2, timeout_s=30, identification=(fake_identify, cell.catalog_for_tests))
    assert not report.ok
    assert any("request on cell/cell1/robot/move differs" in d for d in report.differences)


def test_collect_mode_stores_labelled_images_at_perturbed_poses(cfg, cell, plc, tmp_path) -> None:
    cfg.classifier.dataset_dir = tmp_path
    with FakeCell(cfg, n_viewpoints=3) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        ack = plc.cmd("start", mode="collect", label="dirty", perturb_m=0.01, seed=3, dataset="ds")
        assert ack.accepted, ack.reason
        plc.wait_state("Complete")
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed" and res.verdict is None
    assert [v.label for v in res.viewpoints] == ["dirty"] * 3
    assert "classify" not in fake.calls
    assert len(list((tmp_path / "ds").rglob("*.png"))) == 3


def test_hold_with_a_classification_in_flight_resumes_and_completes(cfg, cell, plc) -> None:
    """The Hold cancels the scanning activation, not the classification overlapping it."""
    with FakeCell(cfg, n_viewpoints=4, move_delay_s=0.1, delays={"classify": 0.6}) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        deadline = time.monotonic() + 10
        while "classify" not in fake.calls and time.monotonic() < deadline:
            time.sleep(0.01)
        assert plc.cmd("hold").accepted  # the first classification is still being answered
        plc.wait_state("Held")
        time.sleep(0.8)
        assert plc.cmd("unhold").accepted
        plc.wait_state("Complete", timeout=30)
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed", res.reason
    assert sorted(v.index for v in res.viewpoints) == list(range(4))
    assert all(v.label == "clean" for v in res.viewpoints)


class _UncertainCell(FakeCell):
    """Every classification uncertain: a cycle with re-looks on would image each viewpoint again."""

    def _classify(self, req, image):
        return super()._classify(req, image).model_copy(update={"uncertain": True})


def test_replay_verify_reruns_a_cycle_with_the_relooks_it_was_recorded_with(cfg, tmp_path) -> None:
    """A log from before re-looks (or with them off) verifies under a config that has them on."""
    from cellctl.geometry.catalog import load_catalog
    from cellctl.recording.replay import read_cycle, verify

    catalog = load_catalog(cfg.path(cfg.catalog))
    cfg.classifier.relook.max_views = 0
    cell = build_cell(cfg, identification=(fake_identify, catalog))
    plc = Plc(cfg)
    try:
        with _UncertainCell(cfg) as fake:
            plc.cmd("reset")
            plc.wait_state("Idle")
            plc.cmd("start")
            plc.wait_state("Complete")
            res = plc.results.get(timeout=5)
            assert fake.calls.count("move") == 3  # no re-look moves were made
    finally:
        plc.close()
        cell.close()
    path = cfg.path(res.log)
    assert read_cycle(path).metadata["cycle"]["relook_max_views"] == "0"
    vcfg = _verify_config(tmp_path / "v", settle_s=0)
    assert vcfg.classifier.relook.max_views > 0
    report = verify(path, vcfg, timeout_s=30, identification=(fake_identify, catalog))
    assert report.ok, report.differences
