"""The HMI's parts without a bus: password hashes, sessions, the login limiter, the MCAP tail."""

from __future__ import annotations

import base64
import hashlib
import json

import pytest

from cellctl.errors import ConfigError
from cellctl.hmi.auth import SessionStore, hash_password, verify_password
from cellctl.hmi.config import load_hmi_config
from cellctl.hmi.live import LiveCycle, McapTail
from cellctl.recording.cycle_log import CycleLog
from tests.hmi.conftest import FakeClock


def test_password_hashes_verify_and_refuse() -> None:
    h = hash_password("correct horse", salt=b"s" * 16)
    assert h.startswith("scrypt$16384$8$1$") and "correct horse" not in h
    assert verify_password("correct horse", h)
    assert not verify_password("correct hors", h)
    assert not verify_password("correct horse", h[:-2] + "AA")
    for bad in ("", "scrypt$x", "md5$abc$def", "scrypt$1$8$1$!!$!!"):
        assert not verify_password("correct horse", bad)
    salt = b"p" * 16
    pb = hashlib.pbkdf2_hmac("sha256", b"other pass", salt, 1000)
    b64 = lambda b: base64.urlsafe_b64encode(b).decode().rstrip("=")  # noqa: E731
    assert verify_password("other pass", f"pbkdf2_sha256$1000${b64(salt)}${b64(pb)}")
    with pytest.raises(ConfigError, match="at least 8"):
        hash_password("short")


def test_sessions_expire_when_idle_or_old_and_nonces_are_single_use() -> None:
    clock = FakeClock()
    store = SessionStore(idle_s=10, max_s=25, clock=clock)
    s = store.create("alice", "operator")
    assert store.get(s.token) == (s, None)
    assert store.get("forged") == (None, "unknown")
    assert s.use_nonce("n1") and not s.use_nonce("n1")
    for _ in range(3):  # kept alive by use, until the absolute limit
        clock.t += 8
        assert store.get(s.token)[0] is s
    clock.t += 2
    assert store.get(s.token) == (None, "expired")
    s2 = store.create("bob", "maintenance")
    clock.t += 11
    assert store.get(s2.token) == (None, "expired")


def test_hmi_config_rejects_unknown_keys_and_plain_passwords(tmp_path) -> None:
    p = tmp_path / "hmi.yaml"
    p.write_text("port: 8081\nusers:\n  - {name: alice, role: operator, password_hash: hunter2}\n")
    with pytest.raises(ConfigError, match="password_hash"):
        load_hmi_config(p)
    p.write_text("prot: 8081\n")
    with pytest.raises(ConfigError, match="unknown key 'prot'"):
        load_hmi_config(p)
    with pytest.raises(ConfigError, match="does not exist"):
        load_hmi_config(tmp_path / "nope.yaml")
    p.write_text("port: 8081\n")
    assert load_hmi_config(p, ["port=9000", "foxglove.enabled=true"]).port == 9000
    with pytest.raises(ConfigError, match="expected KEY.PATH=VALUE"):
        load_hmi_config(p, ["port"])


def test_the_tail_reads_a_log_as_it_grows_and_stops_at_a_partial_record(tmp_path) -> None:
    path = tmp_path / "c.mcap"
    log = CycleLog(path, "c1")
    seen = []
    tail = McapTail(path, seen.append)
    log.write_json("cell/cell1/status", "cellctl/Status", {"state": "Execute", "step": "scanning"})
    assert tail.poll() == 1 and seen[0].topic == "cell/cell1/status"
    log.image("/camera/image", b"\x89PNGfake", "png")
    # cut the file inside the record the writer is "still writing": nothing half-read comes out
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:-5])
    half = []
    t2 = McapTail(cut, half.append)
    assert t2.poll() == 1 and len(half) == 1
    cut.write_bytes(data)
    assert t2.poll() == 1 and half[1].topic == "/camera/image"
    assert tail.poll() == 1
    live = LiveCycle("cell1", "c1")
    for m in seen:
        live.fold(m)
    assert live.image() == (b"\x89PNGfake", "png") and live.step == "scanning" and live.steps_seen == ["scanning"]
    log.close()
    assert tail.poll() == 0  # summary records are not messages
    not_mcap = tmp_path / "x.mcap"
    not_mcap.write_bytes(b"garbage!" * 10)
    assert McapTail(not_mcap, seen.append).poll() == 0
    assert json.loads(seen[0].data)["state"] == "Execute"


def test_the_live_scene_is_a_valid_foxglove_scene_update(cfg) -> None:
    import jsonschema
    import numpy as np

    from cellctl.hmi.config import FoxgloveConfig
    from cellctl.hmi.foxglove_live import FoxgloveLive
    from cellctl.messages import PoseMsg
    from cellctl.recording import foxglove as fx
    from cellctl.recording.replay import RecordedMessage
    from tests.conftest import free_port

    class NoBus:  # the joints arrive below by hand; the view must not need a daemon to draw
        def add_subscriber(self, key: str, cb: object) -> None:
            assert key == f"cell/{cfg.cell_id}/robot/joints"

    link = NoBus()
    live = FoxgloveLive(cfg, FoxgloveConfig(enabled=True, port=free_port()), link)
    try:
        T = np.eye(4)
        T[:3, 3] = (1.0, 0.0, 0.2)
        cam = PoseMsg.from_matrix(T).model_dump(mode="json")
        msgs = [
            ("/bin/identification", {"bin_type": "case_study"}),
            ("/bin/pose", fx.pose_in_frame("base", T)),
            ("/camera/pose", fx.pose_in_frame("base", T)),
            (f"cell/{cfg.cell_id}/planner/lookup/reply", {"hit": True, "viewpoints": [{"camera_pose": cam}] * 3}),
        ]
        for topic, obj in msgs:
            live.forward(RecordedMessage(topic, "x", 1, json.dumps(obj).encode()))

        class Sample:
            payload = type("P", (), {"to_bytes": lambda self: json.dumps({"position": [0.1] * 6}).encode()})()

        live._on_joints(Sample())
        scene = live.scene()
        jsonschema.validate(scene, fx.SCHEMAS["foxglove.SceneUpdate"])
        bin_, arm = scene["entities"]
        assert len(bin_["triangles"][0]["points"]) % 3 == 0 and len(bin_["arrows"]) == 3
        assert len(arm["spheres"]) == 7 and len(arm["lines"]) == 2  # arm links + frustum
        assert len(arm["lines"][1]["points"]) == 16
    finally:
        live.close()
