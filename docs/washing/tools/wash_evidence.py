"""Per-face and per-view evidence of a demo wash-and-verify cycle: the twin's ground truth against
the cell's dirt map and verdicts (docs/washing/README.md, "Why re-inspection kept faces dirty").

    python docs/washing/tools/wash_evidence.py <cycle.mcap> <poll prefix> [plans dir]

<poll prefix>.state.json / .bases.json are written by poll_twin.py during the run (the sim robot's
spray passes and base parks). Sim-only: it reads the ground truth (cellctl.sim.ground_truth).
"""

from __future__ import annotations

import glob
import json
import sys

import numpy as np

from cellctl.config import load_config
from cellctl.geometry.catalog import load_catalog
from cellctl.messages import Intrinsics, PoseMsg, SimState
from cellctl.planning.raycast import RayCaster
from cellctl.recording.replay import read_cycle
from cellctl.sim.ground_truth import PowderField, SprayPass
from cellctl.sim.render import RenderParams, SimRenderer
from cellctl.sim.scene import Scenario

mcap, prefix = sys.argv[1], sys.argv[2]
plans_dir = sys.argv[3] if len(sys.argv) > 3 else None
cfg = load_config(None, [])
cat = load_catalog(cfg.path(cfg.catalog))
st = SimState.model_validate_json(open(prefix + ".state.json").read())
bases = json.load(open(prefix + ".bases.json"))
mesh = cat.load_mesh(st.bin_type)
washes = [SprayPass(np.asarray(m.spots), np.asarray(m.axes), m.radius, m.cos_incidence, m.removal) for m in st.washes or []]
c = read_cycle(mcap)
rounds = [m.json() for m in c.on("/wash/round")]
rt = [m.log_time for m in c.on("/wash/round")]
t_plan1 = c.on("/wash/plan")[0].log_time
res = [m.json() for m in c.on(f"cell/{cfg.cell_id}/result")][-1]
w = res.get("wash") or {}
print("rounds (round, dirty before, after, passes, views, sweeps run, refused):")
print("  ", [(r["round"], r["dirty_faces_before"], r["dirty_faces_after"], r["passes_run"], r["reinspected_views"], r["sweeps_run"], len(r["sweeps_refused"])) for r in rounds])
print("verdict:", w.get("verdict"), w.get("reason"), "seen_fraction", w.get("seen_fraction"))
cum = np.cumsum([r["passes_run"] for r in rounds]).tolist()
print("spray passes per round (cumulative)", cum, "; the twin ran", len(washes))

# powder per face, densely: 40 area samples per face (a face's centroid and corners miss clumps inside large faces)
rng = np.random.default_rng(0)
S = 40
u, v = rng.uniform(size=(2, S))
fl = u + v > 1
u[fl], v[fl] = 1 - u[fl], 1 - v[fl]
tri = mesh.vertices[mesh.faces]
pts = (tri[:, 0][None] + u[:, None, None] * (tri[:, 1] - tri[:, 0])[None] + v[:, None, None] * (tri[:, 2] - tri[:, 0])[None]).reshape(-1, 3)
tags, nrm = np.tile(mesh.surface, S), np.tile(mesh.normals, (S, 1))


def powder(n: int) -> np.ndarray:
    f = PowderField.sample(mesh, st.powder_amount, st.seed)
    f.washes = washes[:n]
    return (f.alpha(pts, tags, nrm).reshape(S, -1) > 0.5).mean(axis=0)


f0 = powder(0)
print(f"powder before the wash: {int((f0 > 0).sum())} faces, {float((f0 * mesh.areas).sum()) * 1e4:.1f} cm2")
listed: set[int] = set()
for f in glob.glob(f"{plans_dir}/*/*/*.json") if plans_dir else []:
    for vp in json.load(open(f))["plan"].get("viewpoints") or []:
        listed |= set(vp.get("faces", []))
req = [m.json() for m in c.messages if m.topic.endswith("planner/wash_plan/request")]
rep = [m.json() for m in c.messages if m.topic.endswith("planner/wash_plan/reply")]
left = np.zeros(mesh.n_faces)
for k, n in enumerate(cum):
    left = powder(n)
    idx = np.flatnonzero(left > 0)
    print(f"after round {k + 1}: powder on {len(idx)} faces, {float((left * mesh.areas).sum()) * 1e4:.1f} cm2")
    q, p = req[k] if k < len(req) else None, rep[k] if k < len(rep) else None
    for fi in idx:
        row = f"   face {fi} surface {mesh.surface[fi]} {mesh.areas[fi] * 1e4:.0f} cm2 powder {left[fi]:.2f} of it"
        if plans_dir:
            row += f"; in a plan's face list: {fi in listed}"
        first = [x for x in zip(req, rep) if x[0]["round"] == k + 1][:1]
        if first:
            dm, pr = first[0]
            sd, sc = set(dm["dirt_map"].get("seen_dirty", [])), set(dm["dirt_map"].get("seen_clean", []))
            unw = {g for x in pr.get("unwashable", []) for g in x["faces"]}
            row += f"; round map {'dirty' if fi in sd else 'clean' if fi in sc else 'unseen'}, target {fi in set(pr.get('targets', []))}, unwashable {fi in unw}"
        print(row)

# every re-inspection view: the classifier's call against the powder its frame shows (twin render)
caps, pend = [], None
for m in c.messages:
    if m.log_time < t_plan1:
        continue
    if m.topic.endswith("camera/capture/reply"):
        pend = (m.log_time, m.json())
    elif m.topic.endswith("classifier/classify/reply") and pend is not None:
        caps.append((pend[0], pend[1], m.json()))
        pend = None
renderer, rc = SimRenderer(cat), RayCaster(mesh.vertices, mesh.faces)
sc0 = Scenario(bin_type=st.bin_type, bin_xyz_yaw=st.bin_xyz_yaw, dirty=True, powder_amount=st.powder_amount, seed=st.seed)
T_world_bin = sc0.T_world_bin(cat.get(st.bin_type))
print("re-inspection views (round, p_dirty, label, uncertain, powder pixels, faces under them, of which listed):")
for t, cap, cl in caps:
    r = sum(1 for x in rt if x < t) + 1
    n = cum[r - 1] if r - 1 < len(cum) else len(washes)
    Tb = np.asarray([b for b in bases if b["t"] * 1e9 <= t][-1]["T"])  # the base's park at the capture
    Tc = Tb @ PoseMsg.model_validate(cap["camera_pose"]).matrix()
    intr = Intrinsics.model_validate(cap["intrinsics"])
    pm = renderer.render(sc0.with_base(Tb), Tc, intr, params=RenderParams(noise_sigma=0), washes=washes[:n]).powder_mask
    faces: list[int] = []
    if pm.any():
        T = np.linalg.inv(T_world_bin) @ Tc
        K = intr.K()
        ys, xs = np.nonzero(pm)
        d = np.stack([(xs + 0.5 - K[0, 2]) / K[0, 0], (ys + 0.5 - K[1, 2]) / K[1, 1], np.ones(len(xs))], 1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        hit, _ = rc.first_hit(np.broadcast_to(T[:3, 3], d.shape), d @ T[:3, :3].T)
        faces = np.unique(hit[hit >= 0]).tolist()
    if cl["label"] == "dirty" or cl["uncertain"] or pm.any():
        n_listed = sum(1 for f in faces if f in listed) if plans_dir else "-"
        print(f"   r{r} p {cl['p_dirty']:.3f} {cl['label']:5} {'unc' if cl['uncertain'] else '   '} powder px {int(pm.sum()):6} on {len(faces)} faces ({n_listed} listed) {faces[:8]}")
