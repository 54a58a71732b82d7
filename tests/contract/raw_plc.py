"""A PLC gateway written against the documented wire contract only: zenoh + json, no cellctl.

Usage: python raw_plc.py ENDPOINT CELL_ID — prints one JSON line per check, exits non-zero
on the first contract violation.
"""

import json
import queue
import sys
import time

import zenoh

endpoint, cell = sys.argv[1], sys.argv[2]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")

with zenoh.open(conf) as s:
    states: "queue.Queue[dict]" = queue.Queue()
    acks: "queue.Queue[dict]" = queue.Queue()
    s.declare_subscriber(f"cell/{cell}/status", lambda x: states.put(json.loads(x.payload.to_bytes())))
    s.declare_subscriber(f"cell/{cell}/cmd/ack", lambda x: acks.put(json.loads(x.payload.to_bytes())))
    time.sleep(0.3)

    def status() -> dict:
        (r,) = list(s.get(f"cell/{cell}/status", timeout=5))
        return json.loads(r.ok.payload.to_bytes())

    def by_query(cmd: dict) -> dict:
        (r,) = list(s.get(f"cell/{cell}/cmd", payload=json.dumps(cmd), timeout=5))
        return json.loads(r.ok.payload.to_bytes())

    def by_put(cmd: dict) -> dict:
        s.put(f"cell/{cell}/cmd", json.dumps(cmd))
        while True:
            ack = acks.get(timeout=5)
            if ack.get("request_id") == cmd.get("request_id"):
                return ack

    def wait(state: str) -> dict:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                st = states.get(timeout=0.5)
            except queue.Empty:
                continue
            if st["state"] == state:
                return st
        raise SystemExit(f"state {state} not reached")

    def check(name: str, ok: bool, detail: object) -> None:
        print(json.dumps({"check": name, "ok": ok, "detail": detail}), flush=True)
        if not ok:
            raise SystemExit(1)

    st = status()
    check("status_readable", st["type"] == "cellctl/Status" and st["state"] == "Stopped" and st["state_code"] == 2, st)
    ack = by_query({"type": "cellctl/Command", "v": 1, "command": "reset", "request_id": "q1"})
    check("reset_by_query", ack["accepted"] and ack["request_id"] == "q1", ack)
    check("reached_idle", wait("Idle")["state_code"] == 4, "Idle")
    ack = by_put({"type": "cellctl/Command", "v": 1, "cntrl_cmd": 2, "request_id": "p2"})
    check("start_by_put_cntrl_cmd", ack["accepted"] and ack["command"] == "start", ack)
    st = wait("Aborted")
    check("aborted_without_workers", "worker alive" in (st["last_error"] or ""), st["last_error"])
    ack = by_query({"type": "cellctl/Command", "v": 1, "command": "start", "request_id": "bad"})
    check("bad_command_rejected", not ack["accepted"] and "not allowed" in ack["reason"], ack)
    ack = by_put({"type": "cellctl/Command", "v": 1, "command": "clear", "request_id": "p3"})
    check("clear_by_put", ack["accepted"], ack)
    wait("Stopped")
    by_query({"type": "cellctl/Command", "v": 1, "command": "reset", "request_id": "q4"})
    wait("Idle")
    ack = by_put({"type": "cellctl/Command", "v": 1, "command": "stop", "request_id": "p5"})
    check("stop_by_put", ack["accepted"], ack)
    wait("Stopped")
    ack = by_query({"type": "cellctl/Command", "v": 1, "command": "abort", "request_id": "q6"})
    check("abort_by_query", ack["accepted"], ack)
    check("aborted", wait("Aborted")["state_code"] == 9, "Aborted")
