"""An outside client sending a burst of hostile puts on the command key: zenoh + json, no cellctl.

Usage: python burst_sender.py ENDPOINT CELL_ID N PAUSE_EVERY PAUSE_S CONGESTION(block|drop) [ACK_DELAY_S [ZENOH_JSON]]
Prints one JSON line: how many were put, and which request ids came back in Acks on cmd/ack.
ACK_DELAY_S > 0 makes this a slow consumer (its Ack callback takes that long, like a busy PLC
gateway): Zenoh's back-pressure then reaches the daemon's transmission queue. ZENOH_JSON is an
object of extra Zenoh config keys (e.g. a small ``transport/link/tcp/so_rcvbuf``).
Every payload is refused by the contract yet carries a readable string ``request_id``.
"""

import json
import sys
import threading
import time

import zenoh

endpoint, cell, n, every, pause, congestion = sys.argv[1:7]
n, every, pause = int(n), int(every), float(pause)
ack_delay = float(sys.argv[7]) if len(sys.argv) > 7 else 0.0
extra = json.loads(sys.argv[8]) if len(sys.argv) > 8 else {}
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")
for k, v in extra.items():
    conf.insert_json5(k, json.dumps(v))

HOSTILE = [
    lambda rid: {"v": 1, "command": "reset", "request_id": rid},  # no type
    lambda rid: {"type": "cellctl/Command", "request_id": rid, "command": "reset"},  # no v
    lambda rid: {"type": "cellctl/Command", "v": 2, "request_id": rid, "command": "reset"},
    lambda rid: {"type": "cellctl/Status", "v": 1, "request_id": rid},
    lambda rid: {"type": "cellctl/Command", "v": 1, "request_id": rid, "command": "jump"},
    lambda rid: {"type": "cellctl/Command", "v": 1, "request_id": rid, "cntrl_cmd": 42},
    lambda rid: {"type": "cellctl/Command", "v": 1, "request_id": rid, "command": "hold"},  # not in Stopped
    lambda rid: {"type": "cellctl/Command", "v": 1, "request_id": rid, "command": "reset", "extra": [1] * 50},
]

acked: list[str | None] = []
lock = threading.Lock()


def on_ack(sample: "zenoh.Sample") -> None:
    rid = json.loads(sample.payload.to_bytes()).get("request_id")
    if ack_delay:
        time.sleep(ack_delay)
    with lock:
        acked.append(rid)


cc = zenoh.CongestionControl.BLOCK if congestion == "block" else zenoh.CongestionControl.DROP
with zenoh.open(conf) as s:
    s.declare_subscriber(f"cell/{cell}/cmd/ack", on_ack)
    time.sleep(0.5)
    key = f"cell/{cell}/cmd"
    t0 = time.monotonic()
    for i in range(n):
        s.put(key, json.dumps(HOSTILE[i % len(HOSTILE)](f"b-{i}")), congestion_control=cc)
        if (i + 1) % every == 0:
            time.sleep(pause)
    sent_s = time.monotonic() - t0
    deadline = time.monotonic() + 30 + n * ack_delay
    while time.monotonic() < deadline:
        with lock:
            if len(acked) >= n:
                break
        time.sleep(0.05)
    time.sleep(0.3)  # any duplicate would arrive now
    with lock:
        got = list(acked)
print(json.dumps({"sent": n, "sent_s": round(sent_s, 3), "acks": len(got), "ids": got}))
