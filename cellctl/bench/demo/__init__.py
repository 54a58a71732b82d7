"""``cellctl demo``'s stories as data: the simulated cell driven the way a PLC would drive it.

A story file (``stories/<name>.yaml``, :mod:`cellctl.bench.demo.stories`) lists the cycles to play:
the sim scenario to set, the Start params, what the CycleResult must say, and the named steps a
cycle runs (:data:`cellctl.bench.demo.runner.STEPS`). The runner plays them over
:class:`cellctl.bus.plc_client.PlcClient` (the wire contract only) against a cell built in this
process. A new story is a new entry or a new file: ``cellctl demo --stories <name or path>``.
"""
