"""The cell's digital twin (sim backends only; the supervisor never imports this package).

* :mod:`cellctl.sim.scene` — scenario (bin type/pose, dirt), parking model, observation poses;
* :mod:`cellctl.sim.collision` — fast batch collision checks of arm + camera vs bin/cell/self;
* :mod:`cellctl.sim.motion` — straight joint line or OMPL RRTConnect paths;
* :mod:`cellctl.sim.render` — ray-traced camera images with a per-pixel powder mask
  (see its docstring for the in-process API used for dataset synthesis);
* :mod:`cellctl.sim.pybullet_world` — the same world in pybullet (DIRECT), cross-check;
* :mod:`cellctl.sim.ground_truth` — true bin pose and true powder (measurement only).

Heavy libraries (open3d, trimesh/embree, ompl, pybullet) are imported inside functions.
"""
