"""Offline viewpoint planning (paper §IV): plain functions on arrays, one stage per module.

``seeds`` → ``viewpoints`` → ``filters`` → ``reach`` → ``visibility`` → ``select`` →
``pathcost`` → ``tour``, run in order by :func:`cellctl.planning.pipeline.make_plan`;
``planfile`` (cache files) and ``adjust`` (pose-tolerance lookup) serve the planner worker.
Nothing heavy is imported here: the supervisor talks to the planner worker over the bus and
never imports OMPL, open3d or trimesh.
"""
