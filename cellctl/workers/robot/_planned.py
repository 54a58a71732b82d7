"""What every arm backend shares: the cell's collision world, planning, the Robot operations.

A :class:`PlannedRobot` owns the **scenario** (bin type and pose, dirt, seed, where the base
parked), because parking error and the bin's pose must be the same for motion, collisions and
(in the twin) the camera's renders; the camera worker reads it through
:class:`~cellctl.messages.SimState`. Motions are joint paths of
:func:`cellctl.sim.motion.plan_path`, time-parametrised by :mod:`cellctl.motion`; a backend
only says how a trajectory is executed (:meth:`PlannedRobot._execute`) and where the joints
come from (:meth:`PlannedRobot._read_joints`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from cellctl.config import CellConfig
from cellctl.errors import CellError, RobotError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import Catalog, load_catalog
from cellctl.geometry.transforms import invert
from cellctl.messages import (
    ApproachReply,
    ApproachRequest,
    MoveReply,
    MoveRequest,
    PoseMsg,
    RobotState,
    SimScenarioRequest,
    SimState,
    SprayPassMsg,
    WashReply,
    WashRequest,
)
from cellctl.motion import UR10E, Trajectory, time_parametrize
from cellctl.sim import scene
from cellctl.sim.collision import CollisionWorld, densify
from cellctl.sim.motion import STEP_RAD, path_length, plan_path
from cellctl.vision.handeye import configured_hand_eye
from cellctl.workers.robot._port import Robot

__all__ = ["DRIVE_S", "FROZEN_GAP_S", "PlannedRobot", "TwinBaseReport"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

DRIVE_S = 4.0
"""Simulated time the mobile base needs to park (divided by speed_scale)."""
FROZEN_GAP_S = 1.0
"""A motion whose control loop stalls this long stops instead of catching up.

Motion is interpolated in wall-clock time, so a worker that was frozen (SIGSTOP, swapped out,
debugger) would otherwise jump to where the path says it should be by now, after the
supervisor may already have aborted the cycle. A real arm's controller does the same on a
missed heartbeat (protective stop). Far above a loaded machine's scheduling jitter.
"""


class PlannedRobot(Robot):
    """A planned-motion arm on the mobile base (subclasses: sim, UR).

    Args:
        cfg: the cell config (``robot``, ``sim``, ``catalog`` sections).
        catalog: an already loaded catalog (default: load ``cfg.catalog``).
        on_change: called (without locks held) after the joints or the scenario changed.

    Raises:
        ConfigError: the catalog or the configured bin type is invalid.
    """

    def __init__(
        self, cfg: CellConfig, catalog: Catalog | None = None, on_change: Callable[[], None] | None = None
    ) -> None:
        self.cfg = cfg
        self.T_flange_cam = configured_hand_eye(cfg)
        """The controller's hand–eye estimate (``robot.hand_eye``); None: the nominal mount."""
        self.catalog = catalog or load_catalog(cfg.path(cfg.catalog))
        s = cfg.sim
        self.catalog.get(s.bin_type)
        x, y, z, yaw_deg = s.bin_pose_xyz_yaw
        self._scenario = scene.Scenario(
            bin_type=s.bin_type,
            bin_xyz_yaw=(x, y, z, float(np.radians(yaw_deg))),
            dirty=s.dirty,
            powder_amount=s.powder_amount,
            seed=s.seed,
        )
        self._q = scene.HOME_JOINTS.copy()
        self._parked = False
        self._park_attempt = 0
        self._busy = threading.Lock()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._stop_reason = ""
        self._moving = False
        self.last_path: NDArray[np.float64] | None = None
        """Waypoints (K, 6) of the last planned motion (for tests and logs)."""
        self.on_change = on_change
        self._washes: list[SprayPassMsg] = []  # twin: spray passes run over this scenario's bin
        self._wash_rays = None  # twin: ray caster of the bin mesh, built on the first wash
        self._world = self._make_world()
        # Stall watch: a thread that ticks every 0.1 s. After a freeze (SIGSTOP, swap, debugger)
        # either it runs first and sees its own gap (→ stop), or the motion thread runs first and
        # sees a stale tick (→ refuses to move): no order of resumption lets a stale motion run.
        self._tick = time.monotonic()
        self._closed = threading.Event()
        threading.Thread(target=self._watch_stalls, name="robot-stall-watch", daemon=True).start()

    # --- world ------------------------------------------------------------------------------

    def _make_world(self) -> CollisionWorld:
        sc = self._scenario
        bt = self.catalog.get(sc.bin_type)
        mesh = self.catalog.load_mesh(sc.bin_type)
        T_world_base = sc.base()
        return CollisionWorld(
            mesh,
            invert(T_world_base) @ sc.T_world_bin(bt),
            invert(T_world_base),
            walls=scene.CABIN_HALF,
            margin=self.cfg.robot.collision_margin_m,
        )

    @property
    def world(self) -> CollisionWorld:
        """Collision world of the current scenario (robot base frame)."""
        return self._world

    @property
    def scenario(self) -> scene.Scenario:
        return self._scenario

    @property
    def joints(self) -> NDArray[np.float64]:
        return self._read_joints()

    def _read_joints(self) -> NDArray[np.float64]:
        with self._lock:
            return self._q.copy()

    def trajectory(self, path: NDArray[np.float64]) -> Trajectory:
        """``path`` timed within the UR10e limits at ``robot.speed_fraction``."""
        return time_parametrize(path, UR10E, self.cfg.robot.speed_fraction, self._accel_fraction())

    def _accel_fraction(self) -> float:
        return 1.0

    def _changed(self) -> None:
        if self.on_change is not None:
            try:
                self.on_change()
            except Exception:  # a publisher problem must not break a motion
                log.exception("robot on_change callback failed")

    # --- motion -----------------------------------------------------------------------------

    def _acquire(self, what: str) -> None:
        if not self._busy.acquire(blocking=False):
            raise RobotError(f"cannot {what}: the robot is busy with another motion (send 'stop' first)")
        self._stop.clear()

    def _execute(self, path: NDArray[np.float64]) -> float:
        """Follow ``path`` (its :meth:`trajectory`); returns the duration (s). Raises RobotError if stopped."""
        raise NotImplementedError

    def _go(self, q_goal: NDArray[np.float64]) -> tuple[float, float]:
        path = self._plan(self.joints, q_goal)
        self.last_path = path
        return path_length(path), self._execute(path)

    def _plan(self, q_start: NDArray[np.float64], q_goal: NDArray[np.float64]) -> NDArray[np.float64]:
        """Direct plan; if RRTConnect gives up, go through the home pose (the hub of free space)."""
        kw = {"timeout_s": self.cfg.robot.plan_timeout_s, "seed": self._scenario.seed}
        try:
            return plan_path(self._world, q_start, q_goal, **kw)
        except RobotError as err:
            if "no collision-free path" not in str(err) or self._world.in_collision(scene.HOME_JOINTS):
                raise
            log.info("direct plan failed (%s); planning via home", err)
            a = plan_path(self._world, q_start, scene.HOME_JOINTS, **kw)
            b = plan_path(self._world, scene.HOME_JOINTS, q_goal, **kw)
            return np.vstack([a, b[1:]])

    def _go_camera(self, T_base_cam: NDArray[np.float64]) -> tuple[float, float]:
        pos = np.round(T_base_cam[:3, 3], 4).tolist()
        sols = rm.ik_camera(T_base_cam, self.joints, self.T_flange_cam)
        if len(sols) == 0:
            why = rm.unreachable_reason(T_base_cam, self.T_flange_cam)
            raise RobotError(f"camera pose at {pos} (base frame) is unreachable: {why}")
        flags = self._world.check(sols)
        free = sols[~flags]
        # prefer solutions whose own links do not block the camera's view (stable sort keeps
        # the nearest-first order otherwise)
        blocked = np.array([rm.view_blocked(q, T_flange_cam=self.T_flange_cam) for q in free], dtype=bool)
        free = np.concatenate([free[~blocked], free[blocked]]) if len(free) else free
        if len(free) == 0:
            why = "; ".join(", ".join(self._world.explain(s)) for s in sols[:2])
            raise RobotError(
                f"camera pose at {pos} (base frame) is unreachable without collision: all {len(sols)} IK "
                f"solutions collide (e.g. {why})"
            )
        last: CellError | None = None
        for q in free[:4]:
            try:
                return self._go(q)
            except RobotError as err:
                if self._stop.is_set():
                    raise
                last = err
        raise RobotError(f"camera pose at {pos}: no collision-free path to any of {len(free)} IK solutions: {last}")

    def _watch_stalls(self) -> None:
        while not self._closed.wait(0.1):
            now = time.monotonic()
            gap = now - self._tick
            if gap > FROZEN_GAP_S and self._busy.locked():  # a request was in progress
                self.stop(f"the robot worker was frozen for {gap:.1f} s")
            self._tick = now  # only after the stop: the motion thread sees a stale tick or the stop

    def close(self) -> None:
        self._closed.set()

    def _check_not_frozen(self, gap_s: float, what: str) -> None:
        if gap_s > FROZEN_GAP_S:
            raise RobotError(
                f"{what} interrupted: the robot worker was frozen for {gap_s:.1f} s (> {FROZEN_GAP_S:g} s); "
                "stopped where it was instead of catching up"
            )

    def _wait(self, seconds: float, what: str) -> None:
        """Wait ``seconds`` unless stopped; a stall longer than the wait counts as a freeze."""
        t0 = time.monotonic()
        if self._stop.wait(seconds):
            raise RobotError(f"{what} stopped ({self._stop_reason or 'stop requested'})")
        self._check_not_frozen(time.monotonic() - t0 - seconds, what)

    def _settle(self, settle_s: float | None) -> None:
        s = self.cfg.robot.settle_s if settle_s is None else settle_s
        if s > 0:
            self._wait(s, "settling")

    # --- Robot interface --------------------------------------------------------------------

    def approach(self, req: ApproachRequest) -> ApproachReply:
        self._acquire("approach")
        try:
            bt = self.catalog.get(self._scenario.bin_type)
            mesh = self.catalog.load_mesh(self._scenario.bin_type)
            # a whole-bin station parks where the plan says (bin frame); else the nominal park
            T_bin_station = None
            if req.base_pose is not None:
                if req.base_pose.frame_id != "bin":
                    raise RobotError(f"base_pose.frame_id is {req.base_pose.frame_id!r}; expected 'bin' (T_bin_base)")
                T_bin_station = req.base_pose.matrix()
            if req.park:
                self._park(bt, mesh, T_bin_station)
            elif not self._parked:
                raise RobotError("cannot go to an observation pose before parking: send approach with park=true")
            if req.observe:
                T_bin_base = T_bin_station if T_bin_station is not None else scene.nominal_T_bin_base(bt, mesh)
                T_base_cam = invert(T_bin_base) @ scene.observation_T_bin_cam(bt, req.observation_index)
                self._go_camera(T_base_cam)
                self._settle(None)
            q = self.joints
            return ApproachReply(
                joints=q.tolist(),
                flange_pose=PoseMsg.from_matrix(rm.fk(q)),
                camera_pose=PoseMsg.from_matrix(rm.camera_pose(q, self.T_flange_cam)),
                observation_index=req.observation_index,
            )
        finally:
            self._busy.release()

    def _park(self, bt, mesh, T_bin_base: NDArray[np.float64] | None = None) -> None:  # BinType, BinMesh
        if np.abs(self.joints - scene.HOME_JOINTS).max() > 1e-6:
            self._go(scene.HOME_JOINTS)  # tuck the arm before the base drives
        self._park_attempt += 1
        T = scene.park(
            self._scenario,
            bt,
            mesh,
            self.cfg.sim.approach_error_m,
            self.cfg.sim.approach_error_deg,
            self._park_attempt,
            T_bin_base,
        )
        self._wait(DRIVE_S / self.cfg.robot.speed_scale, "parking")
        self._scenario = self._scenario.with_base(T)
        self._parked = True
        self._world = self._make_world()
        self._changed()

    def move(self, req: MoveRequest) -> MoveReply:
        self._acquire("move")
        try:
            if req.joints is not None:
                q = rm.check_joints(req.joints, "target joints")
                hits = self._world.explain(q)
                if hits:
                    raise RobotError(f"target joints {np.round(q, 4).tolist()} are in collision: {', '.join(hits)}")
                length, duration = self._go(q)
            else:
                assert req.camera_pose is not None
                if req.camera_pose.frame_id != "base":
                    raise RobotError(
                        f"camera_pose.frame_id is {req.camera_pose.frame_id!r}; expected 'base' (robot base)"
                    )
                length, duration = self._go_camera(req.camera_pose.matrix())
            self._settle(req.settle_s)
            q = self.joints
            return MoveReply(
                joints=q.tolist(),
                camera_pose=PoseMsg.from_matrix(rm.camera_pose(q, self.T_flange_cam)),
                path_length_rad=length,
                duration_s=duration,
            )
        finally:
            self._busy.release()

    def wash(self, req: WashRequest) -> WashReply:
        """Run wash sweeps: a planned collision-free motion to each sweep's first waypoint, then
        its waypoints as one continuous trajectory, ``passes`` times back and forth.

        Every sweep is checked against this robot's collision world (densely, as a planned path
        is) before any motion; a stop interrupts it like any motion. In the twin each completed
        pass is also a spray pass over the bin's powder (:meth:`sim_state` ``washes``).
        """
        self._acquire("wash")
        try:
            paths = []
            for i, sw in enumerate(req.sweeps):
                path = np.asarray(sw.joints, np.float64)
                hit = self._world.check(densify(path, STEP_RAD)) if len(path) > 1 else self._world.check(path)
                if hit.any():
                    q = densify(path, STEP_RAD)[int(np.argmax(hit))] if len(path) > 1 else path[0]
                    raise RobotError(
                        f"wash sweep {i} (of {len(req.sweeps)}, round {req.round}) is in collision at joints "
                        f"{np.round(q, 4).tolist()}: {', '.join(self._world.explain(q))}; no motion"
                    )
                paths.append((path, sw.passes))
            length = duration = 0.0
            passes = 0
            for path, k_passes in paths:
                if float(np.abs(self.joints - path[0]).max()) > 1e-6:
                    dl, dt = self._go(path[0])
                    length, duration = length + dl, duration + dt
                for k in range(k_passes):
                    run = path if k % 2 == 0 else path[::-1]
                    if len(run) > 1:
                        self.last_path = run
                        duration += self._execute(run)
                        length += path_length(run)
                    self._sprayed(run)
                    passes += 1
            return WashReply(
                sweeps_run=len(paths),
                passes_run=passes,
                joints=self.joints.tolist(),
                path_length_rad=length,
                duration_s=duration,
            )
        finally:
            self._busy.release()

    def _sprayed(self, run: NDArray[np.float64]) -> None:
        """Twin only: the pass just run, as a spray pass over the true bin (the jet goes where the arm went)."""
        if not getattr(self, "publishes_twin", False):
            return
        from cellctl.planning.raycast import RayCaster
        from cellctl.washing.nozzle import NozzleModel
        from cellctl.washing.twin import spray_pass

        sc = self._scenario
        nozzle = NozzleModel.from_config(self.cfg.nozzle)
        if self._wash_rays is None:
            mesh = self.catalog.load_mesh(sc.bin_type)
            self._wash_rays = RayCaster(mesh.vertices, mesh.faces)
        T_bin_base = invert(sc.T_world_bin(self.catalog.get(sc.bin_type))) @ sc.base()
        T_bin_noz = T_bin_base @ rm.fk_batch(run) @ nozzle.T_flange_nozzle()
        sp = spray_pass(T_bin_noz, self._wash_rays, nozzle)
        self._washes.append(
            SprayPassMsg(
                spots=[tuple(p) for p in np.round(sp.spots, 5).tolist()],
                axes=[tuple(a) for a in np.round(sp.axes, 5).tolist()],
                radius=sp.radius,
                cos_incidence=sp.cos_incidence,
                removal=sp.removal,
            )
        )
        self._changed()

    def state(self) -> RobotState:
        q = self.joints
        return RobotState(
            joints=q.tolist(),
            flange_pose=PoseMsg.from_matrix(rm.fk(q)),
            camera_pose=PoseMsg.from_matrix(rm.camera_pose(q, self.T_flange_cam)),
            moving=self._moving,
        )

    def stop(self, reason: str) -> None:
        self._stop_reason = reason
        self._stop.set()

    # --- sim only ---------------------------------------------------------------------------

    def set_scenario(self, req: SimScenarioRequest) -> SimState:
        """Change the scenario (bin type/pose, dirt, seed); optionally park again.

        Raises:
            ConfigError: unknown bin type. RobotError: a motion is running.
        """
        self._acquire("change the scenario")
        try:
            if req.bin_type is not None:
                self.catalog.get(req.bin_type)
            upd = {
                k: getattr(req, k)
                for k in ("bin_type", "bin_xyz_yaw", "dirty", "powder_amount", "seed", "park_offset_xy_yaw")
                if getattr(req, k) is not None
            }
            if upd:
                from dataclasses import replace

                self._scenario = replace(self._scenario, **upd)
                self._world = self._make_world()
                self._washes, self._wash_rays = [], None  # a new bin (or new powder) is unwashed
            if req.repark:
                self._park(self.catalog.get(self._scenario.bin_type), self.catalog.load_mesh(self._scenario.bin_type))
            self._changed()
            return self.sim_state()
        finally:
            self._busy.release()

    def sim_state(self, washes: bool = False) -> SimState:
        sc = self._scenario
        bt = self.catalog.get(sc.bin_type)
        return SimState(
            bin_type=sc.bin_type,
            bin_xyz_yaw=sc.bin_xyz_yaw,
            park_offset_xy_yaw=sc.park_offset_xy_yaw,
            dirty=sc.dirty,
            powder_amount=sc.powder_amount,
            seed=sc.seed,
            world_T_bin=PoseMsg.from_matrix(sc.T_world_bin(bt), "world"),
            world_T_base=PoseMsg.from_matrix(sc.base(), "world"),
            parked=self._parked,
            joints=self.joints.tolist(),
            moving=self._moving,
            wash_passes=len(self._washes),
            washes=list(self._washes) if washes else None,
        )


class TwinBaseReport:
    """For a twin-backed :class:`PlannedRobot` (put it first in the bases): the twin parks the base,
    so the twin's base reports its pose, ``ApproachReply.base_pose`` (frame ``map``, the twin's world).

    A station whose board is not visible then gets the bin pose measured at an earlier station
    carried through the base's reported motion, so only the localisation error is left
    unmeasured there, not the parking error. Only the ``sim`` base reports: a ``manual`` one is
    parked by a person, with no localisation to report; a worker without the twin (a real
    controller) knows nothing of the base (a vendor base reports through :meth:`Base.pose`).
    """

    def approach(self, req: ApproachRequest) -> ApproachReply:
        reply = super().approach(req)  # type: ignore[misc]
        twin = getattr(self, "publishes_twin", False)  # a real controller's worker knows nothing of the base
        if not twin or self.cfg.base.backend != "sim" or not self._parked:  # type: ignore[attr-defined]
            return reply
        b = self.cfg.base  # type: ignore[attr-defined]
        T = scene.localised(self._scenario, b.localisation_error_m, b.localisation_error_deg, self._park_attempt)  # type: ignore[attr-defined]
        return reply.model_copy(update={"base_pose": PoseMsg.from_matrix(T, "map")})
