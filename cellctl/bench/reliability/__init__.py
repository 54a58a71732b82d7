"""Reliability runs of the measurement harness: fault injection, fuzzing, soak and the cluster in namespaces.

Each module provides one ``cellctl bench`` measurement (see :mod:`cellctl.cli.bench`); ``sim_cell`` starts the sim
cell they and the other benches drive, ``netns`` and ``relay`` the hosts and links of ``cluster``.
"""
