"""Plays a story file (:mod:`cellctl.bench.demo.stories`) against the simulated cell, as a PLC would.

The daemon runs in this process, the sim workers (robot, camera, classifier, planner) as child
processes, all on the configured loopback endpoint. Each story is one cycle driven over the wire
contract (:class:`~cellctl.bus.plc_client.PlcClient`: Reset, Start, the CycleResult); the sim scenario
is changed between cycles through the sim robot worker's ``scenario`` op. A story's ``steps`` name
what it does, in order (:data:`STEPS`). Outputs go to ``logs/demo-<time>/`` (cycle logs, index, a
fresh plan cache, dirt-map PNGs). The demo fails (exit 1) if any story's checks fail.
"""

from __future__ import annotations

import contextlib
import json
import math
import queue
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cellctl.bench.demo.stories import Story, StoryFile, chosen
from cellctl.bus.plc_client import PlcClient
from cellctl.config import CellConfig
from cellctl.errors import CellError
from cellctl.messages import Command, CycleResult, now_iso

__all__ = ["COMMISSIONER", "STEPS", "DemoOptions", "Row", "fill", "paths", "play", "table"]

COMMISSIONER = "demo:commissioner"
"""The user who declares the demo's bin clean (a commissioning cycle needs a named user)."""

ROLES = ("robot", "camera", "classifier", "planner")


def _say(text: str) -> None:
    print(text, flush=True)


@dataclass
class Row:
    """One line of the demo's closing table."""

    n: int
    story: str
    outcome: str = "-"
    verdict: str = "-"
    viewpoints: str = "-"
    coverage: str = "-"
    surfaces: str = "-"
    stations: str = "-"
    refused: int = 0
    modelled: str = "-"
    seconds: float = 0.0
    note: str = ""
    ok: bool = False


def table(rows: list[Row]) -> str:
    head = (
        f"{'#':>2}  {'story':44} {'outcome':16} {'verdict':10} {'views':>5} {'cover':>6} {'ext/int':>9} {'st':>3} "
        f"{'ref':>3} {'model':>6} {'time':>6}  ok  note"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r.n:>2}  {r.story:44} {r.outcome:16} {r.verdict:10} {r.viewpoints:>5} {r.coverage:>6} {r.surfaces:>9} "
            f"{r.stations:>3} {r.refused:>3} {r.modelled:>6} {r.seconds:>5.1f}s  {'✓' if r.ok else '✗'}   {r.note}"
        )
    lines.append(
        "cover: area of the inspected surface(s) seen; ext/int: per surface; st: stations visited; "
        "ref: viewpoints the arm refused at run time; model: the plan's modelled cycle at the arm's real limits"
    )
    return "\n".join(lines)


def fill(row: Row, res: Any) -> None:
    """The table row's figures from a CycleResult."""
    from cellctl.bench.reliability.soak import refused_viewpoints
    from cellctl.surface import SURFACES

    row.outcome = res.outcome.value
    row.verdict = res.verdict or "-"
    row.viewpoints = str(len(res.viewpoints)) if res.viewpoints else "-"
    row.coverage = f"{res.coverage:.0%}" if res.coverage is not None else "-"
    row.refused = refused_viewpoints(res)[0]  # counted as the soak counts them
    cov = res.coverage_by_surface
    if cov:
        row.surfaces = "/".join(f"{cov[s]:.0%}" if cov.get(s) is not None else "-" for s in SURFACES)
    if res.stations:
        row.stations = str(sum(1 for st in res.stations if st.plan_ids))
    if res.modelled_cycle_s is not None:
        row.modelled = f"{res.modelled_cycle_s:.0f}s"


def paths(res: Any) -> str:
    """What each surface was judged against, and by how many of the result's views."""
    if not res.decision_path:
        return "   decision path: none (no view judged)"
    counts: dict[str, int] = {}
    for v in res.viewpoints:
        if v.label is not None:
            counts[v.decided_by or "detector"] = counts.get(v.decided_by or "detector", 0) + 1
    views = ", ".join(f"{n} by {k}" for k, n in sorted(counts.items()))
    return "   decision path: " + ", ".join(f"{s} {p}" for s, p in res.decision_path.items()) + f" (views: {views})"


@dataclass
class Demo:
    """What every story's steps share: the cell's client, config, outputs and the table so far."""

    cfg: CellConfig
    plc: PlcClient
    out: Path
    cycle_timeout: float
    rows: list[Row] = field(default_factory=list)
    failures: int = 0


@dataclass
class Play:
    """One story being played: its number, its row, its cycle's result once there."""

    n: int
    story: Story
    row: Row
    res: CycleResult | None = None
    plan_ready: bool = False


Step = Callable[[Demo, Play], bool]
"""A story step: False ends the story (its failure is already counted)."""


def _scenario(demo: Demo, play: Play) -> bool:
    """Set the sim world the story needs (nothing sent when it leaves the world as it is)."""
    from cellctl.bus import keys
    from cellctl.bus.rpc import request
    from cellctl.messages import SimScenarioRequest, SimState

    x0, y0, z0, yaw0 = demo.cfg.sim.bin_pose_xyz_yaw
    fields = play.story.scenario.request(demo.cfg.sim.bin_type, (x0, y0, z0, math.radians(yaw0)))
    if fields:
        key = keys.robot_op(demo.cfg.cell_id, "scenario")
        request(demo.plc.session, key, SimScenarioRequest(**fields), SimState, timeout=30, role="robot")
    return True


def _cycle(demo: Demo, play: Play) -> bool:
    """Reset to Idle, Start with the story's params, wait for the CycleResult and the wait state."""
    plc, row = demo.plc, play.row
    _say(f"── cycle {play.n}: {row.story}")
    t0 = time.monotonic()
    if plc.command("reset").accepted:
        plc.wait_for(lambda s: s.state == "Idle", 30)
    ack = plc.command("start", **play.story.start)
    if not ack.accepted:
        row.note = f"start refused: {ack.reason}"
        demo.failures += 1
        return False
    try:
        play.res = plc.results.get(timeout=demo.cycle_timeout)
    except queue.Empty:
        row.note = f"no result within {demo.cycle_timeout:g} s"
        demo.failures += 1
        plc.command("abort")
        return False
    # the result is published while Completing/Aborting; the next Reset needs the wait state
    plc.wait_for(lambda s: s.state in ("Complete", "Aborted", "Stopped"), 30)
    row.seconds = time.monotonic() - t0
    fill(row, play.res)
    return True


def _check(demo: Demo, play: Play) -> bool:
    """The CycleResult against the story's ``expect``; the row says what differs."""
    res, exp, row = play.res, play.story.expect, play.row
    assert res is not None  # the cycle step ran
    problems = []
    if res.outcome.value != exp.outcome:
        problems.append(f"expected {exp.outcome}: {res.reason}")
    if exp.verdict is not None and res.verdict != exp.verdict:
        problems.append(f"expected verdict {exp.verdict}")
    if exp.adjusted is not None and res.plan_adjusted != exp.adjusted:
        problems.append(f"expected plan_adjusted={exp.adjusted}, got {res.plan_adjusted}")
    if exp.washed and (res.wash is None or not res.wash.rounds):
        problems.append("expected a wash round: the scan found nothing to wash")
    elif exp.washed and res.log and res.wash is not None:  # the story's pictures: each round's before, path, after
        folder = demo.cfg.path(res.log).parent / f"{res.cycle_id}.wash"
        missing = [p for r in res.wash.rounds for p in r.pictures if not (folder / p).is_file()]
        short = [r.round for r in res.wash.rounds if len(r.pictures) < 3]
        if missing or short:
            problems.append(f"wash pictures missing: {missing or short}")
    row.ok = not problems
    row.note = "; ".join(problems) or (res.reason or "")[:60]
    demo.failures += bool(problems)
    return True


def _decision_path(demo: Demo, play: Play) -> bool:
    """Print what each surface was judged against (references / enrolled / shipped)."""
    _say(paths(play.res))
    return True


def _wash_report(demo: Demo, play: Play) -> bool:
    """wash_and_verify: print the rounds, the dirty faces per round and where their pictures are."""
    res, row = play.res, play.row
    if res is None or res.wash is None:
        return True
    w = res.wash
    pics = [p for r in w.rounds for p in r.pictures]
    why = f": {w.reason}" if w.reason else ""
    seen = f" on {w.seen_fraction:.0%} of the bin's area seen" if w.seen_fraction is not None else ""
    counts = [r.dirty_faces_before for r in w.rounds[:1]] + [r.dirty_faces_after for r in w.rounds]
    faces = " → ".join(map(str, counts))
    _say(f"   wash {w.verdict or '-'} after {len(w.rounds)} round(s){seen}{why}; dirty faces {faces}")
    for p in pics:
        _say(f"   picture {demo.cfg.path(res.log).parent / f'{res.cycle_id}.wash' / p}" if res.log else p)
    row.note = (row.note + f" wash: {len(w.rounds)} round(s), {len(pics)} pictures").strip()
    return True


def _dirt_map(demo: Demo, play: Play) -> bool:
    """Draw the completed cycle's dirt map (one PNG per surface of a whole-bin cycle); never fails the story."""
    res, row, i = play.res, play.row, play.n
    if res is None or not res.dirt_map or res.outcome.value != "completed":
        return True
    try:
        from cellctl.geometry.catalog import load_catalog
        from cellctl.recording.dirt_map import draw_dirt_map

        cfg, out = demo.cfg, demo.out
        mesh = load_catalog(cfg.path(cfg.catalog)).load_mesh(res.bin.type or cfg.sim.bin_type)
        title = f"cycle {i}: verdict {res.verdict}"
        if res.coverage_by_surface:  # whole bin: one picture per surface (the cavity on its own)
            pngs = [
                draw_dirt_map(mesh, res.dirt_map, out / f"dirt-map-cycle{i}-{s}.png", title, surface=s)
                for s, c in res.coverage_by_surface.items()
                if c is not None
            ]
        else:
            pngs = [draw_dirt_map(mesh, res.dirt_map, out / f"dirt-map-cycle{i}.png", title)]
        row.note = (row.note + " map: " + ", ".join(p.name for p in pngs)).strip()
    except Exception as err:  # a picture must not fail the story
        _say(f"   (dirt map not drawn: {err})")
    return True


def _wait_plan(demo: Demo, play: Play) -> bool:
    """Follow the planning job the cycle submitted (replan_required) to its end, printing its progress."""
    res, row = play.res, play.row
    if res is None or not res.planner_job_id:
        return True
    _say(f"   planning job {res.planner_job_id} running offline:")
    shown: set[str] = set()

    def show(p: Any) -> None:
        line = f"   [{p.fraction:4.0%}] {p.stage} {p.message or ''}"
        if line not in shown:
            _say(line)
            shown.add(line)

    end = demo.plc.wait_plan_job(res.planner_job_id, demo.cycle_timeout, show)
    play.plan_ready = end is not None and end.state == "done"
    if not play.plan_ready:
        row.ok = False
        row.note = "planning job did not finish"
        demo.failures += 1
    return True


def _commission(demo: Demo, play: Play) -> bool:
    """After the story's plan is made: the commissioning cycle of the clean bin (Start ``mode=commission`` in
    maintenance, by :data:`COMMISSIONER`), a row of its own; back to production after it."""
    if play.plan_ready:
        demo.rows.append(_commissioning(demo.plc, play.n, demo.cycle_timeout))
        demo.failures += not demo.rows[-1].ok
    return True


def _commissioning(plc: PlcClient, n: int, timeout: float) -> Row:
    row = Row(n, "clean bin declared clean → commissioning")
    _say(f"── cycle {n}: {row.story} (maintenance, {COMMISSIONER})")
    t0 = time.monotonic()
    try:
        plc.to_idle()
    except CellError as err:
        row.note = str(err)
        return row
    ack = plc.unit_mode("maintenance", user=COMMISSIONER)
    if ack.accepted:
        params = {"mode": "commission"}
        ack = plc.send(
            Command(command="start", user=COMMISSIONER, params=params, request_id=plc.next_id(), stamp=now_iso())
        )
    if not ack.accepted:
        row.note = f"commissioning refused: {ack.reason}"
        return row
    try:
        res = plc.results.get(timeout=timeout)
    except queue.Empty:
        row.note = f"no result within {timeout:g} s"
        plc.command("abort")
        return row
    plc.wait_for(lambda s: s.state in ("Complete", "Aborted", "Stopped"), 30)
    row.seconds = time.monotonic() - t0
    fill(row, res)
    c = res.commission
    row.ok = res.outcome.value == "completed" and c is not None
    if c is not None:
        enrolled = ", ".join(c.enrolled) or "none"
        problems = "; ".join(f"{s}: {why}" for s, why in c.problems.items())
        _say(f"   reference set v{c.version} of {c.bin_type}: {c.references} views; enrolled {enrolled}")
        if problems:
            _say(f"   not enrolled: {problems}")
        row.note = f"set v{c.version}, {c.references} references"
    else:
        row.note = f"expected a reference set: {res.reason}"
    _say(paths(res))
    try:
        plc.to_idle()
        back = plc.unit_mode("production", user=COMMISSIONER).accepted
    except CellError:
        back = False
    if not back:
        row.ok, row.note = False, "could not return to production"
    return row


def _clear(demo: Demo, play: Play) -> bool:
    """A failed or aborted cycle: Clear, so the next story starts from Stopped."""
    if play.res is not None and play.res.outcome.value in ("failed", "aborted"):
        demo.plc.command("clear")
        demo.plc.wait_for(lambda s: s.state == "Stopped", 30)
    return True


STEPS: dict[str, Step] = {
    "scenario": _scenario,
    "cycle": _cycle,
    "check": _check,
    "decision_path": _decision_path,
    "wash_report": _wash_report,
    "dirt_map": _dirt_map,
    "wait_plan": _wait_plan,
    "commission": _commission,
    "clear": _clear,
}
"""The steps a story may name (``stories.StepName`` lists the same names; tests/test_demo_stories.py checks it)."""


@dataclass
class DemoOptions:
    """What ``cellctl demo`` was asked (cellctl/cli/demo.py's arguments)."""

    stories: StoryFile
    wash: bool = True
    wanted: list[int] | None = None
    out: Path | None = None
    robot: str | None = None
    worker_timeout: float = 240.0
    cycle_timeout: float = 1800.0
    config: str | None = None
    overrides: list[str] = field(default_factory=list)


def _overrides(opts: DemoOptions, out: Path) -> list[str]:
    from cellctl.config import output_overrides

    # a Python emulator on a shared machine sends late packages now and then: the thresholds of cell_ur.yaml
    ur = ["robot.backend=ur", "robot.ur.twin=true", "robot.ur.faults.data_stale_ms=1000"]
    ur = [*ur, "robot.ur.faults.watchdog_hz=1"] if opts.robot == "ur" else []
    # the twin renders a powdered bin in 2-6 s, 10.0 s once at load 12 (a demo cycle failed on the 10 s default)
    slow = ["supervisor.timeouts.capture=30"]
    return [*slow, *opts.stories.overrides, *opts.overrides, *ur, *output_overrides(out)]


def play(opts: DemoOptions) -> int:
    """Play the chosen stories of ``opts.stories`` on a cell built here; the table and a JSON summary at the end.

    Returns:
        0 when every story's checks held, else 1.

    Raises:
        ConfigError: a bad config, override or story number.
    """
    import datetime as _dt

    from cellctl.app import build_cell
    from cellctl.config import load_config

    t_demo = time.monotonic()
    now = _dt.datetime.now()
    out = load_config(opts.config, opts.overrides).path(opts.out or Path("logs") / f"demo-{now:%Y%m%d-%H%M%S}")
    overrides = _overrides(opts, out)
    cfg = load_config(opts.config, overrides)
    _say(f"cellctl demo — cell {cfg.cell_id!r} on {cfg.bus.listen}, outputs in {out}")
    stories = chosen(opts.stories.played(opts.wash), opts.wanted)

    def _terminate(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt(f"signal {signum}")  # unwinds the cell: workers stopped, logs closed

    signal.signal(signal.SIGTERM, _terminate)
    stack = contextlib.ExitStack()
    if cfg.robot.backend == "ur" and cfg.robot.ur.twin:  # the UR backend drives the emulated controller
        from cellctl.sim.ur_controller import EmulatorProcess

        _say(f"starting the emulated UR10e controller on {cfg.robot.ur.host} …")
        out.mkdir(parents=True, exist_ok=True)
        stack.enter_context(EmulatorProcess(cfg.robot.ur.host, overrides, opts.config, out / "ur-controller.log"))
    with stack, build_cell(cfg, with_workers=True, config_file=opts.config, overrides=overrides) as cell:
        plc = PlcClient(cfg, "demo", on_event=lambda ev: _say("   · " + ev.text))
        demo = Demo(cfg, plc, out, opts.cycle_timeout)
        _say("starting workers (robot, camera, classifier, planner) …")
        if not plc.wait_workers(ROLES, opts.worker_timeout):
            _say(f"workers did not come up within {opts.worker_timeout:g} s: {cell.supervisor.status.workers}")
            return 1
        _say("all workers alive\n")
        for n, story in stories:
            one = Play(n, story, Row(n, story.title(cfg.sim.bin_type)))
            demo.rows.append(one.row)
            for name in story.steps:
                if not STEPS[name](demo, one):
                    break
        plc.close()
    _say("\n" + table(demo.rows))
    summary = {
        "cycles": len(demo.rows),
        "failed": demo.failures,
        "refused_viewpoints": sum(r.refused for r in demo.rows),
        "whole_bin": cfg.planner.whole.enabled,
        "wall_s": round(time.monotonic() - t_demo, 1),
        "out": str(out),
    }
    _say(json.dumps(summary))
    return 1 if demo.failures else 0
