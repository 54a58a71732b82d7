"""Poll the sim robot's state on a running demo's bus (``poll_twin.py <port> <prefix>``): the twin's spray
passes (``<prefix>.state.json``, the most passes seen: a later scenario change clears them) and every base
park (``<prefix>.bases.json``, wall time of the change). Ground truth for wash_evidence.py; sim-only."""
import argparse, json, sys, time
from cellctl.config import load_config
from cellctl.bus.session import open_session
from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.messages import SimStateRequest, SimState
ap = argparse.ArgumentParser(); ap.add_argument("port"); ap.add_argument("out"); a = ap.parse_args()
cfg = load_config(None, [f'bus.listen=["tcp/127.0.0.1:{a.port}"]', f'bus.connect=["tcp/127.0.0.1:{a.port}"]'])
s = open_session(cfg, "client")
last = None; bases = []; fails = 0
while True:
    try:
        st, _ = request(s, keys.sim_state(cfg.cell_id), SimStateRequest(washes=False), SimState, timeout=10, role="robot")
        fails = 0
    except Exception as e:
        fails += 1
        if fails > 60: break
        time.sleep(2); continue
    b = st.world_T_base.matrix().tolist()
    if not bases or bases[-1]["T"] != b:
        bases.append({"t": time.time(), "T": b, "passes": st.wash_passes})
        json.dump(bases, open(a.out + ".bases.json", "w"))
    if st.wash_passes != last and st.wash_passes >= (last or 0):
        try:
            full, _ = request(s, keys.sim_state(cfg.cell_id), SimStateRequest(washes=True), SimState, timeout=20, role="robot")
            open(a.out + ".state.json", "w").write(full.model_dump_json())
            last = full.wash_passes
        except Exception as e:
            print("full fail", e, flush=True)
    time.sleep(1.0)
