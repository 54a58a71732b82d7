"""Planner worker over real Zenoh (loopback router, multicast off): jobs, progress, lookup."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from cellctl.bus import keys
from cellctl.bus.codec import decode_as
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import load_config
from cellctl.errors import WorkerFailed
from cellctl.geometry.catalog import write_ply
from cellctl.geometry.transforms import invert
from cellctl.hashing import file_sha256
from cellctl.messages import (
    PlanJobProgress,
    PlanJobQuery,
    PlanJobReply,
    PlanJobRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PoseMsg,
)
from cellctl.planning.shapes import open_box_bin
from cellctl.workers.planner import PlannerService, run_worker
from tests.conftest import free_port


@pytest.fixture(scope="module")
def box_catalog(tmp_path_factory) -> Path:
    """A catalog with one bin type, ``box``: the small open box bin."""
    d = tmp_path_factory.mktemp("cat")
    m = open_box_bin((0.8, 0.6, 0.8), max_edge=0.1)
    write_ply(d / "box.ply", m.vertices, m.faces, m.internal.astype(int))
    cat = {
        "bins": {
            "box": {
                "mesh": str(d / "box.ply"),
                "mesh_sha256": file_sha256(d / "box.ply"),
                "height_m": 0.8,
                "top_hole_radius_m": 0.28,
                "board": {
                    "squares_x": 5,
                    "squares_y": 4,
                    "square_m": 0.04,
                    "marker_m": 0.03,
                    "first_id": 0,
                    "T_bin_board": [[1, 0, 0, -0.1], [0, 0, 1, -0.3], [0, -1, 0, -0.1], [0, 0, 0, 1]],
                },
            }
        }
    }
    (d / "bins.yaml").write_text(yaml.safe_dump(cat))
    return d / "bins.yaml"


def _cfg(tmp_path: Path, catalog: Path, port: int):
    ep = f'["tcp/127.0.0.1:{port}"]'
    return load_config(
        None,
        [f"bus.listen={ep}", f"bus.connect={ep}", f"catalog={catalog}", f"planner.plans_dir={tmp_path / 'plans'}"],
    )


# robot base pose in the bin frame (as in conftest) → bin pose in the base frame for the wire
_T_BIN_BASE = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, -0.95], [0.0, 0.0, 1.0, -0.1], [0, 0, 0, 1.0]])


def test_job_progress_result_and_lookup_over_zenoh(tmp_path, box_catalog):
    port = free_port()
    cfg = _cfg(tmp_path, box_catalog, port)
    router = open_session(cfg, "router")
    stop = threading.Event()
    worker = threading.Thread(target=run_worker, args=(cfg, None, stop), daemon=True)
    worker.start()
    progress: list[PlanJobProgress] = []
    sub = router.declare_subscriber(
        keys.planner_job_progress(cfg.cell_id),
        lambda s: progress.append(decode_as(PlanJobProgress, s.payload.to_bytes())),
    )
    try:
        alive_key = keys.alive(cfg.cell_id, "planner") + "/*"
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not list(router.liveliness().get(alive_key, timeout=1.0)):
            time.sleep(0.1)
        pose = PoseMsg.from_matrix(invert(_T_BIN_BASE))
        miss, _ = request(
            router,
            keys.worker_op(cfg.cell_id, "planner", "lookup"),
            PlanLookupRequest(bin_type="box", bin_pose=pose),
            PlanLookupReply,
            timeout=20,
        )
        assert not miss.hit and "no plan for bin type 'box'" in miss.reason
        with pytest.raises(WorkerFailed, match="unknown"):
            request(
                router,
                keys.planner_jobs(cfg.cell_id),
                PlanJobRequest(bin_type="barrel", bin_pose=pose),
                PlanJobReply,
                timeout=10,
            )
        sub_reply, _ = request(
            router,
            keys.planner_jobs(cfg.cell_id),
            PlanJobRequest(bin_type="box", bin_pose=pose, seed_pct=4),
            PlanJobReply,
            timeout=10,
        )
        assert sub_reply.state == "queued"
        job = sub_reply.job_id
        state = sub_reply
        deadline = time.monotonic() + 80
        while time.monotonic() < deadline and state.state not in ("done", "failed"):
            time.sleep(0.3)
            state, _ = request(
                router, keys.planner_jobs(cfg.cell_id), PlanJobQuery(job_id=job), PlanJobReply, timeout=10
            )
        assert state.state == "done", state.reason
        assert state.plan_id and (tmp_path / "plans" / "box" / "external" / f"{state.plan_id}.json").is_file()
        stages = {p.stage for p in progress if p.job_id == job}
        assert {"generate_filter", "reachability", "visibility", "selection", "done"} <= stages
        hit, _ = request(
            router,
            keys.worker_op(cfg.cell_id, "planner", "lookup"),
            PlanLookupRequest(bin_type="box", bin_pose=pose),
            PlanLookupReply,
            timeout=20,
        )
        assert hit.hit and hit.plan_id == state.plan_id and not hit.adjusted and hit.viewpoints
        assert [v.index for v in hit.viewpoints] == list(range(len(hit.viewpoints)))
        assert all(len(v.joints) == 6 and v.faces for v in hit.viewpoints)
    finally:
        sub.undeclare()
        stop.set()
        worker.join(timeout=10)
        router.close()


def test_job_of_a_dead_worker_reads_as_failed(tmp_path, box_catalog):
    cfg = _cfg(tmp_path, box_catalog, free_port())
    svc = PlannerService(cfg, "t1")
    try:
        svc._write_record("t1-dead", state="running")
        rec = svc._record_path("t1-dead")
        text = rec.read_text()
        # rewrite the record as if another process (now gone) owned the job
        from cellctl.planning.planfile import read_document, write_document

        data = read_document(rec)
        data["pid"] = 2**22 + 12345  # beyond pid_max on this machine: no such process
        write_document(data, rec)
        assert text != rec.read_text()
        st = svc.job_state("t1-dead")
        assert st.state == "failed" and "died" in st.reason
        assert svc.job_state("nope").state == "failed"
    finally:
        svc.close()
