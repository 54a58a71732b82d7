"""Geometry of the cell: frames (:mod:`~cellctl.geometry.transforms`), the bin catalog
(:mod:`~cellctl.geometry.catalog`, :mod:`~cellctl.geometry.boards`,
:mod:`~cellctl.geometry.bin_meshes`) and the UR10e model (:mod:`~cellctl.geometry.robot_model`).

Light: importing these modules loads numpy/pydantic/yaml only (the supervisor uses them);
OpenCV, trimesh and ur-analytic-ik are imported inside the functions that need them.
"""
