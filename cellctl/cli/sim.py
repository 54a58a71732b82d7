"""``cellctl sim render`` and ``cellctl bins list|generate``: the twin from the command line.

* ``cellctl sim render --bin TYPE [--dirty] --out FILE.png`` — overview picture of the cell
  (robot parked beside the bin, arm at observation pose 0, board, powder if dirty);
  ``--view camera`` renders what the eye-in-hand camera sees instead.
* ``cellctl sim ur-controller [--host 127.0.0.x]`` — an emulated UR10e controller for ur-rtde
  (RTDE 30004, script 30003/30002, dashboard 29999, fault injection on
  ``sim.ur_controller.control_port``: ``echo protective_stop | nc 127.0.0.1 30099``).
* ``cellctl bins list`` — the catalog: type, faces, board ids, size, mesh sha256.
* ``cellctl bins generate`` — regenerate meshes, board images and ``config/bins.yaml``.
"""

from __future__ import annotations

import argparse
import sys

from cellctl.cli import add_config_arguments, config_from_args

__all__ = ["register"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="the simulated cell (twin)")
    ss = p.add_subparsers(dest="sim_cmd", metavar="SUBCOMMAND", required=True)
    r = ss.add_parser("render", help="write a picture of the simulated cell")
    r.add_argument("--bin", dest="bin_type", default=None, help="bin type (default: sim.bin_type)")
    r.add_argument("--dirty", action="store_true", help="scatter powder on the bin")
    r.add_argument("--powder", type=float, default=None, help="powder amount 0..1 (default: sim.powder_amount)")
    r.add_argument("--seed", type=int, default=None, help="scenario seed (parking error, powder)")
    r.add_argument("--view", choices=("overview", "camera"), default="overview")
    r.add_argument("--width", type=int, default=1280)
    r.add_argument("--height", type=int, default=720)
    r.add_argument("--out", required=True, help="PNG file to write")
    add_config_arguments(r)
    r.set_defaults(func=render)
    u = ss.add_parser("ur-controller", help="emulate a UR10e controller on loopback (for robot.backend: ur)")
    u.add_argument("--host", default=None, help="loopback address (default: sim.ur_controller.host)")
    add_config_arguments(u)
    u.set_defaults(func=ur_controller)

    b = sub.add_parser("bins", help="the bin catalog")
    bs = b.add_subparsers(dest="bins_cmd", metavar="SUBCOMMAND", required=True)
    ls = bs.add_parser("list", help="print the catalog")
    add_config_arguments(ls)
    ls.set_defaults(func=bins_list)
    g = bs.add_parser("generate", help="regenerate models/bins/* and config/bins.yaml from the designs")
    add_config_arguments(g)
    g.set_defaults(func=bins_generate)


def ur_controller(args: argparse.Namespace) -> int:
    import threading

    from cellctl.cli.worker import install_stop_signals
    from cellctl.sim import ur_controller as emu

    cfg = config_from_args(args)
    stop = threading.Event()
    install_stop_signals(stop)
    emu.run(cfg, stop, args.host)
    return 0


def render(args: argparse.Namespace) -> int:
    import dataclasses

    import cv2
    import numpy as np

    from cellctl.errors import ConfigError
    from cellctl.geometry import robot_model as rm
    from cellctl.geometry.camera import D435_COLOR
    from cellctl.geometry.catalog import load_catalog
    from cellctl.geometry.transforms import invert, look_at
    from cellctl.sim import scene
    from cellctl.sim.collision import CollisionWorld
    from cellctl.sim.render import RenderParams, SimRenderer

    cfg = config_from_args(args)
    cat = load_catalog(cfg.path(cfg.catalog))
    name = args.bin_type or cfg.sim.bin_type
    bt = cat.get(name)
    mesh = cat.load_mesh(name)
    if args.width < 16 or args.height < 16:
        raise ConfigError(f"--width/--height {args.width}x{args.height} too small; expected at least 16x16")
    sc = scene.Scenario(
        bin_type=name,
        dirty=bool(args.dirty),
        powder_amount=cfg.sim.powder_amount if args.powder is None else float(args.powder),
        seed=cfg.sim.seed if args.seed is None else args.seed,
    )
    sc = sc.with_base(scene.park(sc, bt, mesh, cfg.sim.approach_error_m, cfg.sim.approach_error_deg, 1))
    world = CollisionWorld(mesh, invert(sc.base()) @ sc.T_world_bin(bt), invert(sc.base()))
    T_cam = invert(scene.nominal_T_bin_base(bt, mesh)) @ scene.observation_T_bin_cam(bt, 0)
    sols = [q for q in rm.ik_camera(T_cam, scene.HOME_JOINTS) if not world.in_collision(q)]
    q = sols[0] if sols else scene.HOME_JOINTS
    K = D435_COLOR.at_resolution(args.width, args.height)
    if args.view == "overview":
        K = dataclasses.replace(K, fx=0.75 * K.fx, fy=0.75 * K.fy)  # a wider lens for the overview
    if args.view == "overview":
        T_world_bin = sc.T_world_bin(bt)
        target = T_world_bin[:3, 3] + np.array([0.0, 0.0, -0.45 * bt.height_m])
        side = T_world_bin[:3, :3] @ np.array([1.6, -2.3, 0.0])
        eye = target + side + np.array([0.0, 0.0, 1.5])
        T_world_cam = look_at(eye, (target + sc.base()[:3, 3]) / 2)
    else:
        T_world_cam = sc.base() @ rm.camera_pose(q)
    params = RenderParams(noise_sigma=cfg.camera.noise_sigma)
    out = SimRenderer(cat).render(sc, T_world_cam, K, joints=q, params=params)
    if not cv2.imwrite(args.out, out.rgb[..., ::-1]):
        raise ConfigError(f"cannot write {args.out!r}")
    print(
        f"{args.out}: {name} ({'dirty' if sc.dirty else 'clean'}), {args.view} view "
        f"{args.width}x{args.height}, powder on {int(out.powder_mask.sum())} px",
        file=sys.stderr,
    )
    return 0


def bins_list(args: argparse.Namespace) -> int:
    from cellctl.geometry.catalog import load_catalog
    from cellctl.surface import INTERNAL

    cfg = config_from_args(args)
    cat = load_catalog(cfg.path(cfg.catalog))
    head = f"{'type':<12} {'faces':>6} {'int':>5} {'height':>7} {'hole r':>7} {'board ids':<10} {'board':<12}"
    print(head + " mesh sha256")
    for t in cat:
        m = cat.load_mesh(t.name)
        b = t.board
        ids = f"{b.ids.start}..{b.ids.stop - 1}"
        board = f"{b.squares_x}x{b.squares_y}@{b.square_m * 1000:g}mm"
        print(
            f"{t.name:<12} {m.n_faces:>6} {int((m.surface == INTERNAL).sum()):>5} {t.height_m:>6.3f}m "
            f"{t.top_hole_radius_m:>6.3f}m {ids:<10} {board:<12} {t.mesh_sha256}"
        )
    return 0


def bins_generate(args: argparse.Namespace) -> int:
    from cellctl.geometry.bin_meshes import generate_catalog
    from cellctl.geometry.catalog import load_catalog

    cfg = config_from_args(args)
    path = generate_catalog(cfg.root)
    cat = load_catalog(path)
    for t in cat:
        cat.load_mesh(t.name)
    print(f"wrote {path} ({len(cat)} bin types) and models/bins/", file=sys.stderr)
    return 0
