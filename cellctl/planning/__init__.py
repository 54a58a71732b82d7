"""Offline viewpoint planning (paper §IV): plain functions on arrays, one stage per module.

``seeds`` → ``viewpoints`` → ``filters`` → ``reach`` → ``visibility`` → ``select`` →
``pathcost`` → ``tour``, run in order by :func:`cellctl.planning.pipeline.make_plan`, which
returns a typed :class:`cellctl.planning.plan.Plan`; ``planfile`` (cache files) and ``adjust``
(pose-tolerance lookup) serve the planner worker. The bin mesh is
:class:`cellctl.geometry.catalog.BinMesh`, collisions are :mod:`cellctl.sim.collision`'s
(``collision.PlanningWorld`` adapts them).
Nothing heavy is imported here: the supervisor talks to the planner worker over the bus and
never imports OMPL, open3d or trimesh.
"""
