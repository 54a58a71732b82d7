// cellctl HMI: one script for every page. Live data come from /api/stream (server-sent events);
// commands are POSTs carrying the session's CSRF token and a fresh nonce.
"use strict";

const PAGE = document.body.dataset.page;
const ABNORMAL = new Set(["Aborting", "Aborted"]);
const WARN = new Set(["Holding", "Held", "Suspending", "Suspended"]);
const STEPS = ["approaching", "identifying", "checking_cache", "replanning", "scanning", "classifying", "reporting"];
const MODES = ["production", "maintenance", "manual"];
let session = { user: null };
let last = null; // the last update from the stream

const $ = (id) => document.getElementById(id);
function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v; else if (k.startsWith("on")) e.addEventListener(k.slice(2), v); else e.setAttribute(k, v);
  }
  for (const c of children) e.append(c instanceof Node ? c : document.createTextNode(c == null ? "" : String(c)));
  return e;
}
function setText(id, v) { const e = $(id); if (e) e.textContent = v == null || v === "" ? "—" : String(v); }
function nonce() {
  const b = new Uint8Array(18); crypto.getRandomValues(b);
  return btoa(String.fromCharCode(...b)).replace(/\+/g, "-").replace(/\//g, "_").replace(/=+$/, "");
}
function time(iso) { if (!iso) return "—"; const d = new Date(iso); return isNaN(d) ? iso : d.toLocaleString(); }
function pct(x) { return x == null ? "—" : (100 * x).toFixed(2) + " %"; }
// each surface's seen share against what `clean` needs: "external 34 % (needs 60 %), internal 0 % (needs 60 %)"
function seenText(seen, need) {
  if (!seen) return "—";
  return Object.entries(seen).map(([s, f]) => `${s} ${f == null ? "?" : (100 * f).toFixed(0) + " %"}`
    + (need && need[s] ? ` (needs ${(100 * need[s]).toFixed(0)} %)` : "")).join(", ");
}
function verdictClass(v) { return v === "dirty" ? "verdict-dirty" : v === "incomplete" ? "verdict-incomplete" : ""; }

async function post(url, body) {
  const r = await fetch(url, {
    method: "POST", credentials: "same-origin",
    headers: { "Content-Type": "application/json", "X-CSRF-Token": session.csrf || "" },
    body: JSON.stringify(body || {}),
  });
  let data = {};
  try { data = await r.json(); } catch (e) { data = { error: `HTTP ${r.status}` }; }
  if (r.status === 401) { session = { user: null }; renderWho(); }
  return { ok: r.ok, status: r.status, data };
}

async function loadSession() {
  const r = await fetch("/api/session", { credentials: "same-origin" });
  session = await r.json();
  renderWho();
}

function renderWho() {
  const logged = !!session.user;
  $("who-name").textContent = logged ? `${session.user} (${session.role})` : (session.expired ? "session expired: read-only" : "read-only");
  $("login-link").classList.toggle("hidden", logged);
  $("logout-btn").classList.toggle("hidden", !logged);
  if (last) render(last);
}

$("logout-btn").addEventListener("click", async () => {
  await post("/api/logout", {});
  session = { user: null }; renderWho();
});
for (const a of document.querySelectorAll("[data-nav]")) a.classList.toggle("active", a.dataset.nav === PAGE);

// --- the stream ---------------------------------------------------------------------------------

function connect() {
  const es = new EventSource("/api/stream");
  es.addEventListener("update", (ev) => { last = JSON.parse(ev.data); render(last); });
  es.addEventListener("reach", (ev) => { if (last) { Object.assign(last, JSON.parse(ev.data)); render(last); } });
  es.onerror = () => showUnreachable("HMI server unreachable: reconnecting …");
}

function showUnreachable(text) {
  const b = $("unreachable");
  b.textContent = text || ""; b.classList.toggle("hidden", !text);
}

function render(d) {
  const st = d.status;
  if (!st && !d.reachable) { const chip = $("hdr-state"); chip.textContent = "unreachable"; chip.className = "state-chip abnormal"; }
  showUnreachable(d.reachable ? "" : `CELL UNREACHABLE: ${d.error || "no status"}${st ? ` (last known state ${st.state})` : ""}`);
  if (st) {
    setText("cell-name", st.cell);
    const chip = $("hdr-state");
    chip.textContent = d.reachable ? st.state : `${st.state}?`;
    chip.className = "state-chip" + (ABNORMAL.has(st.state) || !d.reachable ? " abnormal" : WARN.has(st.state) ? " warn" : "");
    setText("hdr-mode", st.unit_mode);
  }
  const open = (d.alarms || []).filter((a) => !a.acked_by).length;
  const ac = $("alarm-count"); ac.textContent = open; ac.classList.toggle("hidden", open === 0);
  if (PAGE === "overview") renderOverview(d);
  else if (PAGE === "live") renderLive(d);
  else if (PAGE === "events") renderEvents(d);
  else if (PAGE === "history") historyTick(d);
  else if (PAGE === "review") reviewTick(d);
}

// --- overview ------------------------------------------------------------------------------------

const LAYOUT = {
  Unholding: [1, 0], Held: [2, 0], Holding: [3, 0],
  Idle: [0, 1], Starting: [1, 1], Execute: [2, 1], Completing: [3, 1], Complete: [4, 1],
  Resetting: [0, 2], Unsuspending: [1, 2], Suspended: [2, 2], Suspending: [3, 2],
  Stopped: [0, 3], Stopping: [1, 3], Clearing: [2, 3], Aborted: [3, 3], Aborting: [4, 3],
};
const BW = 112, BH = 34, GX = 172, GY = 80, OX = 10, OY = 16;
function centre(name) { const [c, r] = LAYOUT[name]; return [OX + c * GX + BW / 2, OY + r * GY + BH / 2]; }
function clip(x0, y0, x1, y1) {
  // where the line from the centre (x0,y0) towards (x1,y1) leaves the box
  const dx = x1 - x0, dy = y1 - y0;
  const t = Math.min(dx ? (BW / 2) / Math.abs(dx) : Infinity, dy ? (BH / 2) / Math.abs(dy) : Infinity);
  return [x0 + dx * t, y0 + dy * t];
}
const SVGNS = "http://www.w3.org/2000/svg";
function svg(tag, attrs, text) {
  const e = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text != null) e.textContent = text;
  return e;
}
let packml = null;
async function drawPackml() {
  packml = await (await fetch("/api/packml")).json();
  const root = $("packml");
  root.replaceChildren();
  const defs = svg("defs", {});
  const marker = svg("marker", { id: "arrow", viewBox: "0 0 10 10", refX: "9", refY: "5", markerWidth: "7", markerHeight: "7", orient: "auto-start-reverse" });
  marker.append(svg("path", { d: "M 0 0 L 10 5 L 0 10 z", fill: "#777" }));
  defs.append(marker); root.append(defs);
  for (const e of packml.edges) {
    if (e.label === "stop" || e.label === "abort" || !LAYOUT[e.from] || !LAYOUT[e.to]) continue;
    const [ax, ay] = centre(e.from), [bx, by] = centre(e.to);
    const [sx, sy] = clip(ax, ay, bx, by), [tx, ty] = clip(bx, by, ax, ay);
    const skip = Math.abs(ax - bx) > GX * 1.5 && Math.abs(ay - by) < 1; // same row, over a box: bend below
    const d = skip ? `M ${sx} ${ay + BH / 2} Q ${(ax + bx) / 2} ${ay + BH / 2 + 34} ${tx} ${by + BH / 2}` : `M ${sx} ${sy} L ${tx} ${ty}`;
    root.append(svg("path", { d, class: "edge", "marker-end": "url(#arrow)", "data-from": e.from, "data-label": e.label }));
    if (e.label !== "SC") {
      const mx = skip ? (ax + bx) / 2 : (sx + tx) / 2, my = skip ? ay + BH / 2 + 22 : (sy + ty) / 2 - 3;
      root.append(svg("text", { x: mx + 3, y: my, class: "edge-label" }, e.label));
    }
  }
  for (const s of packml.states) {
    if (!LAYOUT[s.name]) continue;
    const [c, r] = LAYOUT[s.name];
    const g = svg("g", { id: `st-${s.name}`, "data-state": s.name });
    g.append(svg("rect", { x: OX + c * GX, y: OY + r * GY, width: BW, height: BH, rx: s.acting ? 12 : 2, class: s.acting ? "acting" : "wait" }));
    g.append(svg("text", { x: OX + c * GX + BW / 2, y: OY + r * GY + BH / 2 + 4, "text-anchor": "middle" }, s.name));
    root.append(g);
  }
  if (last) render(last);
}

function renderOverview(d) {
  const st = d.status;
  if (!st) return;
  for (const g of document.querySelectorAll("#packml g[data-state]")) {
    const cur = g.dataset.state === st.state;
    g.classList.toggle("current", cur);
    g.classList.toggle("abnormal", cur && ABNORMAL.has(st.state));
    g.classList.toggle("warn", cur && WARN.has(st.state));
  }
  for (const p of document.querySelectorAll("#packml path.edge")) {
    // the ways out of the current state: the commands allowed now, or its State Complete
    p.classList.toggle("allowed", p.dataset.from === st.state && (p.dataset.label === "SC" || st.available_commands.includes(p.dataset.label)));
  }
  setText("ov-state", `${st.state} (${st.state_code})`);
  $("ov-state").className = ABNORMAL.has(st.state) ? "abnormal" : WARN.has(st.state) ? "warn" : "";
  setText("ov-mode", `${st.unit_mode}${st.unit_mode_code ? ` (${st.unit_mode_code})` : ""}`);
  setText("ov-step", st.step);
  setText("ov-cycle", st.cycle_id);
  $("ov-error").textContent = st.last_error || "none";
  $("ov-error").className = st.last_error ? "abnormal" : "";
  // command buttons: only what the cell accepts now, only for a logged-in user
  const box = $("cmd-buttons");
  const can = !!session.user && d.reachable;
  const want = can ? st.available_commands : [];
  if (box.dataset.cmds !== want.join(",")) {
    box.dataset.cmds = want.join(",");
    box.replaceChildren(...want.map((c) => el("button", { id: `cmd-${c}`, type: "button", onclick: () => sendCommand({ command: c }) }, c[0].toUpperCase() + c.slice(1))));
  }
  $("cmd-hint").textContent = !session.user ? "Log in to command the cell." : !d.reachable ? "The cell is unreachable: no commands." : `Commands allowed in ${st.state}.`;
  const modes = $("mode-buttons");
  const maint = can && session.role === "maintenance";
  modes.classList.toggle("hidden", !maint);
  if (maint && !modes.childElementCount) {
    modes.append(...MODES.map((m) => el("button", { id: `mode-${m}`, type: "button", onclick: () => sendCommand({ unit_mode: m }) }, `Mode: ${m}`)));
  }
  const ws = $("workers");
  ws.replaceChildren(...Object.entries(st.workers || {}).map(([r, up]) => el("li", { class: up ? "up" : "down" }, `${r}: ${up ? "alive" : "MISSING"}`)));
  const ad = st.admin || {};
  setText("ad-processed", ad.prod_processed_count);
  setText("ad-defective", ad.prod_defective_count);
  setText("ad-stop", ad.stop_reason || "none");
  const lc = ad.last_cycle;
  const link = $("ad-last"); link.replaceChildren();
  if (lc) link.append(el("a", { href: `/history?cycle=${encodeURIComponent(lc.cycle_id)}` }, lc.cycle_id), ` ${lc.outcome}${lc.verdict ? ", " + lc.verdict : ""}`,
    ...(lc.verdict === "incomplete" ? [el("span", { class: "verdict-incomplete" }, ` seen: ${seenText(lc.coverage_by_surface, lc.min_seen_fraction)}`)] : []));
  else link.textContent = "—";
  $("ad-warnings").textContent = (ad.warnings || []).join("; ") || "none";
  $("ad-warnings").className = (ad.warnings || []).length ? "warn" : "";
}

async function sendCommand(body) {
  const out = $("cmd-result");
  out.textContent = "sending …"; out.className = "small";
  const r = await post("/api/cmd", { ...body, params: {}, nonce: nonce() });
  const what = body.command || `unit mode ${body.unit_mode}`;
  if (r.ok) { out.textContent = `${what}: accepted (${r.data.ack.state})`; }
  else { out.textContent = `${what}: ${r.data.error || "HTTP " + r.status}`; out.className = "small error-text"; }
}

// --- live ------------------------------------------------------------------------------------------

let liveImageSeq = null, liveHeatSeq = null;
function renderLive(d) {
  const lv = d.live, st = d.status;
  const box = $("stations");
  if (!box.childElementCount) box.append(...STEPS.map((s) => el("li", { id: `station-${s}` }, s.replace("_", " "))));
  if (!lv) { setText("lv-cycle", "no cycle yet"); return; }
  setText("lv-cycle", lv.cycle_id);
  const running = st && st.cycle_id === lv.cycle_id && st.step;
  const cur = running ? st.step : lv.step;
  const finished = !!lv.outcome;
  STEPS.forEach((s) => {
    const li = $(`station-${s}`);
    li.classList.toggle("current", !finished && s === cur);
    li.classList.toggle("done", (lv.steps_seen || []).includes(s) && (finished || s !== cur));
  });
  setText("lv-k", lv.viewpoint); setText("lv-n", lv.n_viewpoints);
  const frac = lv.n_viewpoints ? Math.min(1, (finished ? lv.n_viewpoints : lv.captured) / lv.n_viewpoints) : (finished ? 1 : 0);
  $("lv-bar").style.width = `${(100 * frac).toFixed(1)}%`;
  const state = st && (st.cycle_id === lv.cycle_id || finished) ? st.state : lv.state;
  let text = state || "—";
  if (finished) text += ` — ${lv.outcome}${lv.verdict ? ", verdict " + lv.verdict : ""}${lv.coverage != null ? ", coverage " + pct(lv.coverage) : ""}`
    + (lv.verdict === "incomplete" ? ` (seen: ${seenText(lv.coverage_by_surface, lv.min_seen_fraction)})` : "");
  const oc = $("lv-outcome"); oc.textContent = text;
  oc.className = "outcome" + (ABNORMAL.has(state) || lv.outcome === "failed" || lv.outcome === "aborted" ? " state-chip abnormal" : "");
  if (lv.image_seq != null && lv.image_seq !== liveImageSeq) {
    liveImageSeq = lv.image_seq;
    const img = $("lv-img");
    img.src = `/api/live/image?seq=${lv.image_seq}`;
    img.classList.remove("hidden"); $("lv-noimg").classList.add("hidden");
  }
  const hm = lv.heat_map;
  const heatKey = hm ? `${lv.cycle_id}:${hm.seq}` : null;
  if (heatKey !== liveHeatSeq) {
    liveHeatSeq = heatKey;
    const himg = $("lv-heatimg");
    if (hm) himg.src = `/api/live/heatmap?cycle=${encodeURIComponent(lv.cycle_id)}&seq=${hm.seq}`;
    himg.classList.toggle("hidden", !hm); $("lv-noheat").classList.toggle("hidden", !!hm);
  }
  $("lv-heat").textContent = hm ? `heat map of verdict #${hm.view} over its image: ${hm.label || "—"}${hm.p_dirty != null ? ` p=${hm.p_dirty.toFixed(2)}` : ""} (black clean → yellow dirty)`
    : "Heat map: none yet.";
  $("lv-views").replaceChildren(...lv.verdicts.map((v) => el("tr", {}, el("td", {}, v.n),
    el("td", { class: v.label === "dirty" ? "verdict-dirty" : "" }, v.label || `error: ${v.error || "?"}`),
    el("td", {}, v.p_dirty == null ? "—" : v.p_dirty.toFixed(3)))));
  const dirty = lv.verdicts.filter((v) => v.label === "dirty").length;
  $("lv-summary").textContent = `${lv.verdicts.length} classified, ${dirty} dirty${lv.reason ? " · " + lv.reason : ""}`;
}

// --- history ---------------------------------------------------------------------------------------

let histLastCycle = undefined, selected = null;
function historyTick(d) {
  const lc = d.status && d.status.admin && d.status.admin.last_cycle ? d.status.admin.last_cycle.cycle_id : null;
  if (lc !== histLastCycle) { histLastCycle = lc; loadHistory(); }
}
let histBefore = null;
async function loadHistory(older = false) {
  const q = new URLSearchParams();
  for (const [k, v] of new FormData($("filters"))) if (v) q.set(k, v);
  if (older && histBefore != null) q.set("before", histBefore);
  const r = await fetch(`/api/cycles?${q}`);
  const data = await r.json();
  $("hist-error").textContent = r.ok ? "" : data.error;
  if (!r.ok) return;
  histBefore = data.cycles.length ? data.cycles[data.cycles.length - 1].seq : null;
  $("hist-older").classList.toggle("hidden", data.cycles.length < 50);
  $("hist-rows").replaceChildren(...data.cycles.map((c) => {
    const tr = el("tr", { "data-cycle": c.cycle_id, onclick: () => openCycle(c.cycle_id) },
      el("td", { class: "mono" }, c.cycle_id), el("td", {}, time(c.started)),
      el("td", { class: "nowrap" }, c.duration_s == null ? "—" : `${c.duration_s.toFixed(1)} s`),
      el("td", { class: c.outcome === "failed" || c.outcome === "aborted" || c.outcome === "interrupted" ? "level-error" : "" }, c.outcome || "running"),
      el("td", { class: verdictClass(c.verdict) }, c.verdict || "—"),
      el("td", {}, c.bin_type || "—"), el("td", { class: "small" }, (c.reason || "").slice(0, 90)));
    if (c.cycle_id === selected) tr.classList.add("selected");
    return tr;
  }));
}
async function openCycle(id) {
  selected = id;
  for (const tr of document.querySelectorAll("#hist-rows tr")) tr.classList.toggle("selected", tr.dataset.cycle === id);
  history.replaceState(null, "", `/history?cycle=${encodeURIComponent(id)}`);
  const r = await fetch(`/api/cycles/${encodeURIComponent(id)}/record`);
  const d = await r.json();
  if (!r.ok) { $("hist-error").textContent = d.error; return; }
  $("detail").classList.remove("hidden");
  const res = d.result || {}, row = d.row;
  setText("dt-id", id);
  setText("dt-outcome", `${row.outcome || "running"}${row.reason ? " — " + row.reason : ""}`);
  setText("dt-verdict", row.verdict);
  $("dt-verdict").className = verdictClass(row.verdict);
  setText("dt-coverage", pct(res.coverage));
  setText("dt-seen", seenText(res.coverage_by_surface, res.min_seen_fraction));
  setText("dt-time", `${time(row.started)} → ${time(row.finished)}${row.duration_s != null ? ` (${row.duration_s.toFixed(1)} s)` : ""}`);
  setText("dt-bin", row.bin_type);
  setText("dt-plan", `${row.plan_id || "—"}${res.plan_adjusted ? " (adjusted to the measured pose)" : ""}`);
  const rl = d.release || {};
  $("dt-release").textContent = releaseText(rl);
  $("dt-release").className = rl.state === "review_required" || rl.state === "ready" ? "release-open" : "";
  const au = d.audit || {};
  $("dt-audit").textContent = au.status === "ok" ? `ok — row hash, chain link and log sha256 check (head #${au.head ? au.head.seq : "?"})`
    : `${au.status}${au.findings && au.findings.length ? ": " + au.findings.join("; ") : au.error ? ": " + au.error : ""}`;
  $("dt-audit").className = au.status === "tamper" ? "abnormal" : "";
  const lg = $("dt-log");
  lg.href = `/api/cycles/${encodeURIComponent(id)}/log`; lg.classList.toggle("hidden", !d.log);
  const img = $("dt-dirt");
  img.classList.add("hidden"); $("dt-nodirt").classList.remove("hidden");
  if (res.dirt_map) {
    $("dt-nodirt").textContent = "drawing the dirt map …";
    img.onload = () => { img.classList.remove("hidden"); $("dt-nodirt").classList.add("hidden"); };
    img.onerror = () => { $("dt-nodirt").textContent = "no dirt map"; };
    img.src = `/api/cycles/${encodeURIComponent(id)}/dirt_map.png`;
  } else { $("dt-nodirt").textContent = "no dirt map"; }
  $("dt-views").replaceChildren(...d.images.map((v) => el("figure", { class: "thumb" + (v.label === "dirty" ? " dirty" : "") },
    el("img", { src: `/api/cycles/${encodeURIComponent(id)}/images/${v.image}`, alt: `view ${v.index}`, loading: "lazy" }),
    ...(v.heatmap != null ? [el("img", { src: `/api/cycles/${encodeURIComponent(id)}/heatmaps/${v.image}`, alt: `heat map of view ${v.index}`, loading: "lazy" })] : []),
    el("figcaption", {}, `view ${v.index ?? "?"}: ${v.label || "—"}${v.p_dirty != null ? ` p=${v.p_dirty.toFixed(2)}` : ""}`))));
  if (!d.images.length) $("dt-views").append(el("p", { class: "muted" }, "no scanning images in this cycle"));
}

// --- review ----------------------------------------------------------------------------------------

const REVIEWERS = new Set(["operator", "qa"]);
// "released (clean) by alice at …", "review required: 2 uncertain view(s) open", "auto (clean): no uncertain view"
function releaseText(r) {
  if (!r || !r.state) return "—";
  if (r.state === "released") return `released: ${r.released_verdict} — by ${r.released_by}, ${time(r.released_at)}`;
  if (r.state === "auto") return `released as recorded (${r.released_verdict || "—"}): ${r.uncertain_views ? "review not required" : "no uncertain view"}`;
  if (r.state === "review_required") return `review required: ${r.open_uncertain.length} of ${r.uncertain_views} uncertain view(s) open`;
  if (r.state === "ready") return `reviewed (${r.reviewed_verdict}): ready to release`;
  if (r.state === "not_applicable") return "no verdict to release";
  return `${r.state}${r.error ? ": " + r.error : ""}`;
}
let rvSelected = null, rvLastCycle;
function reviewTick(d) {
  const lc = d.status && d.status.admin && d.status.admin.last_cycle ? d.status.admin.last_cycle.cycle_id : null;
  if (lc !== rvLastCycle) { rvLastCycle = lc; loadQueue(); }
}
async function loadQueue() {
  const r = await fetch(`/api/review/queue?state=${encodeURIComponent($("rv-state").value)}`);
  const data = await r.json();
  $("rv-error").textContent = r.ok ? "" : data.error;
  if (!r.ok) return;
  setText("rv-gate", data.require_for_uncertain ? "review.require_for_uncertain: on" : "off: verdicts stand as recorded");
  $("rv-rows").replaceChildren(...data.items.map((it) => {
    const tr = el("tr", { "data-item": it.id, onclick: () => openItem(it.cycle_id, it.image) },
      el("td", { class: "mono small" }, it.cycle_id), el("td", {}, it.viewpoint ?? "?"), el("td", {}, it.surface || "—"),
      el("td", { class: it.why === "dirty" ? "verdict-dirty" : "verdict-incomplete" }, it.why),
      el("td", {}, it.p_dirty == null ? "—" : it.p_dirty.toFixed(2)),
      el("td", {}, it.decision ? `${it.decision.label} (${it.decision.user})` : "open"));
    if (it.id === rvSelected) tr.classList.add("selected");
    return tr;
  }));
  if (!data.items.length) $("rv-rows").append(el("tr", {}, el("td", { colspan: 6, class: "muted" }, "nothing to review")));
}
function showImg(id, missingId, src) {
  const img = $(id), miss = missingId ? $(missingId) : null;
  img.classList.add("hidden"); if (miss) miss.classList.remove("hidden");
  if (!src) return;
  img.onload = () => { img.classList.remove("hidden"); if (miss) miss.classList.add("hidden"); };
  img.src = src;
}
async function openItem(cycle, n) {
  rvSelected = `${cycle}/${n}`;
  for (const tr of document.querySelectorAll("#rv-rows tr")) tr.classList.toggle("selected", tr.dataset.item === rvSelected);
  const base = `/api/cycles/${encodeURIComponent(cycle)}`;
  const r = await fetch(`/api/review/items/${encodeURIComponent(cycle)}/${n}`);
  const it = await r.json();
  if (!r.ok) { $("rv-error").textContent = it.error; return; }
  $("rv-item").classList.remove("hidden");
  $("rv-msg").textContent = "";
  setText("rv-id", it.id);
  setText("rv-cls", `${it.label || "—"}${it.uncertain ? ", uncertain" : ""}${it.p_dirty != null ? `, p(dirty) ${it.p_dirty.toFixed(2)}` : ""}${it.model_id ? ` — ${it.model_id}` : ""}`);
  setText("rv-surface", `${it.surface}${it.station != null ? `, station ${it.station}` : ""}, bin ${it.bin_type || "—"}`);
  setText("rv-decision", it.decision ? `${it.decision.label} — ${it.decision.user} (${it.decision.role}), ${time(it.decision.time)}: ${it.decision.reason}` : "open");
  setText("rv-verdict", it.release.verdict);
  $("rv-verdict").className = verdictClass(it.release.verdict);
  $("rv-release").textContent = releaseText(it.release);
  $("rv-release").className = it.release.state === "review_required" || it.release.state === "ready" ? "release-open" : "";
  showImg("rv-img", null, `${base}/images/${n}`);
  showImg("rv-heat", "rv-noheat", it.heatmap ? `${base}/heatmaps/${n}` : null);
  const ref = it.reference;
  $("rv-ref").textContent = ref ? "loading the reference …" : "no reference (this view's plan is not commissioned)";
  showImg("rv-refimg", "rv-ref", ref ? `/api/review/items/${encodeURIComponent(cycle)}/${n}/reference` : null);
  $("rv-refcap").textContent = ref ? `reference: set v${ref.version}, viewpoint ${ref.viewpoint} (declared clean by ${ref.declared_by})` : "reference";
  showImg("rv-bin", "rv-nobin", it.bin_picture ? `${base}/dirt_map.png` : null);
  $("rv-faces").textContent = it.faces ? `bin: faces ${it.faces.join(", ")}` : "bin: the cycle's dirt map (the view's faces are not in the record)";
  const can = !!session.user && REVIEWERS.has(session.role);
  const open = !it.decision && it.release.state !== "released";
  $("rv-form").classList.toggle("hidden", !can);
  for (const b of ["rv-dirty", "rv-clean"]) { $(b).disabled = !open; $(b).classList.toggle("hidden", !open); }
  $("rv-release-btn").classList.toggle("hidden", it.release.state !== "ready");
  $("rv-hint").textContent = !session.user ? "Log in as an operator or qa user to review."
    : can ? "" : `Your role (${session.role}) cannot review: an operator or qa user confirms views.`;
}
async function decide(label) {
  const [cycle, n] = [rvSelected.slice(0, rvSelected.lastIndexOf("/")), rvSelected.slice(rvSelected.lastIndexOf("/") + 1)];
  const reason = $("rv-reason").value.trim();
  if (reason.length < 3) { $("rv-msg").textContent = "give a reason (at least 3 characters)"; return; }
  const r = await post(`/api/review/items/${encodeURIComponent(cycle)}/${n}`, { label, reason, nonce: nonce() });
  if (!r.ok) { $("rv-msg").textContent = r.data.error; return; }
  $("rv-reason").value = "";
  await loadQueue(); await openItem(cycle, Number(n));
}
async function releaseCycle() {
  const cycle = rvSelected.slice(0, rvSelected.lastIndexOf("/")), n = Number(rvSelected.slice(rvSelected.lastIndexOf("/") + 1));
  const r = await post(`/api/cycles/${encodeURIComponent(cycle)}/release`, { reason: $("rv-reason").value.trim() || "reviewed", nonce: nonce() });
  if (!r.ok) { $("rv-msg").textContent = r.data.error; return; }
  await openItem(cycle, n);
}

// --- events ----------------------------------------------------------------------------------------

function renderEvents(d) {
  const logged = !!session.user;
  $("alarm-hint").classList.toggle("hidden", logged);
  $("alarms").replaceChildren(...(d.alarms || []).map((a) => el("tr", {},
    el("td", { class: "nowrap" }, time(a.stamp)), el("td", { class: a.acked_by ? "" : `level-${a.level}` }, a.level),
    el("td", {}, a.text), el("td", { class: "mono small" }, a.cycle_id || "—"),
    el("td", {}, a.acked_by ? `${a.acked_by}, ${time(a.acked_at)}` : logged
      ? el("button", { type: "button", id: `ack-${a.id}`, onclick: () => ackAlarm(a.id) }, "Acknowledge") : "open"))));
  if (!(d.alarms || []).length) $("alarms").append(el("tr", {}, el("td", { colspan: 5, class: "muted" }, "no alarms")));
  $("events").replaceChildren(...(d.events || []).map((e) => el("tr", {},
    el("td", { class: "nowrap" }, time(e.stamp)), el("td", { class: `level-${e.level}` }, e.level), el("td", { class: "small" }, e.source), el("td", {}, e.text))));
}
async function ackAlarm(id) {
  const r = await post(`/api/alarms/${id}/ack`, { nonce: nonce() });
  if (!r.ok) alert(r.data.error);
}

// --- login -----------------------------------------------------------------------------------------

function initLogin() {
  $("login-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const r = await fetch("/api/login", {
      method: "POST", credentials: "same-origin", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ user: $("login-user").value, password: $("login-password").value }),
    });
    const data = await r.json();
    if (r.ok) { location.href = "/"; return; }
    $("login-msg").textContent = data.error || `HTTP ${r.status}`;
    $("login-password").value = "";
  });
}

// --- start -----------------------------------------------------------------------------------------

loadSession().then(() => {
  if (PAGE === "login") initLogin();
  if (PAGE === "overview") drawPackml();
  if (PAGE === "review") {
    $("rv-state").addEventListener("change", () => loadQueue());
    $("rv-dirty").addEventListener("click", () => decide("dirty"));
    $("rv-clean").addEventListener("click", () => decide("clean"));
    $("rv-release-btn").addEventListener("click", () => releaseCycle());
    loadQueue();
  }
  if (PAGE === "history") {
    $("filters").addEventListener("submit", (ev) => { ev.preventDefault(); loadHistory(); });
    $("hist-older").addEventListener("click", () => loadHistory(true));
    const id = new URLSearchParams(location.search).get("cycle");
    loadHistory().then(() => { if (id) openCycle(id); });
    histLastCycle = null;
  }
  connect();
});
