"""The request helper tells 'no worker', 'worker hung' and 'worker refused' apart."""

from __future__ import annotations

import threading
import time

import pytest

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.errors import ProtocolError, RobotError, WorkerFailed, WorkerTimeout, WorkerUnavailable
from cellctl.messages import MoveReply, MoveRequest, PoseMsg, RobotState, StopRequest
from cellctl.workers._server import WorkerServer

POSE = PoseMsg(position=(0.0, 0.0, 1.0))


@pytest.fixture
def bus(cfg):
    router = open_session(cfg, "router")
    worker = open_session(cfg, "client")
    client = open_session(cfg, "client")
    yield router, worker, client
    client.close()
    worker.close()
    router.close()


def test_no_worker_is_unavailable_at_once(cfg, bus) -> None:
    _, _, client = bus
    t0 = time.perf_counter()
    with pytest.raises(WorkerUnavailable, match="0 replies"):
        request(client, keys.robot_op("cell1", "move"), MoveRequest(joints=[0] * 6), MoveReply, timeout=5, role="robot")
    assert time.perf_counter() - t0 < 1.0


def test_hung_worker_times_out_refusal_is_failed_and_worker_keeps_serving(cfg, bus) -> None:
    _, wsession, client = bus
    release = threading.Event()

    def move(req: MoveRequest, _: bytes | None) -> MoveReply:
        if req.joints and req.joints[0] > 9:
            raise RobotError(f"target joints {req.joints} are out of limits")
        if req.joints and req.joints[0] < 0:
            release.wait(5)
        if req.joints and req.joints[0] == 7:
            raise ZeroDivisionError("bug")
        return MoveReply(joints=req.joints or [], camera_pose=POSE)

    with WorkerServer(wsession, "cell1", "robot") as srv:
        srv.serve("move", MoveRequest, move)
        srv.serve("stop", StopRequest, lambda r, _: r)
        time.sleep(0.2)
        key = keys.robot_op("cell1", "move")
        with pytest.raises(WorkerTimeout, match="within 0.3 s"):
            request(client, key, MoveRequest(joints=[-1] * 6), MoveReply, timeout=0.3, role="robot")
        # while 'move' is blocked, 'stop' is served on its own thread
        stop, _ = request(client, keys.robot_op("cell1", "stop"), StopRequest(reason="t"), StopRequest, timeout=2)
        assert stop.reason == "t"
        release.set()
        with pytest.raises(WorkerFailed, match=r"out of limits"):
            request(client, key, MoveRequest(joints=[10] * 6), MoveReply, timeout=2, role="robot")
        with pytest.raises(WorkerFailed, match="ZeroDivisionError"):
            request(client, key, MoveRequest(joints=[7] * 6), MoveReply, timeout=2, role="robot")
        with pytest.raises(ProtocolError, match="answered move with cellctl/MoveReply"):
            request(client, key, MoveRequest(joints=[1] * 6), RobotState, timeout=2, role="robot")
        reply, _ = request(client, key, MoveRequest(joints=[1] * 6), MoveReply, timeout=2, role="robot")
        assert reply.joints == [1] * 6
        # garbage to the worker: an error reply, and it keeps serving
        (bad,) = list(client.get(key, payload=b"garbage", timeout=2))
        assert bad.ok is None and b"not valid JSON" in bad.err.payload.to_bytes()
        reply, _ = request(client, key, MoveRequest(joints=[2] * 6), MoveReply, timeout=2, role="robot")
        assert reply.joints == [2] * 6
