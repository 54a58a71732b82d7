"""The measurement harness: benches, reliability runs (faults, soak, fuzz, cluster) and the demo's
stories, kept out of the runtime.

The runtime packages (supervisor, workers, bus, planning, classify, vision, washing, gateway, hmi,
recording, ...) import nothing from here; only ``cellctl.cli`` and this package do
(tests/test_harness_boundary.py). A bench measures the runtime through its public functions and
its wire contract, the way a plant integrator's tooling would.
"""
