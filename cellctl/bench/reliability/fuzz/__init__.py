"""Seeded hostile-payload fuzzing of the PLC command key (``cellctl bench fuzz``, ``tests/fuzz``).

:class:`CommandFuzzer` makes payloads from one ``random.Random(seed)``: random bytes, broken
UTF-8, truncated JSON, recursion bombs, oversize payloads, wrong types for every field, unknown
fields, wrong message type or version, bad ``cntrl_cmd`` codes, NaN/Infinity, hostile Start
params, repeated keys, BOMs and UTF-16, and valid commands (which move the machine) mixed in.

:class:`FuzzTarget` sends each case to a running cell, by query or by put, and checks the
command contract on every one:

* exactly one Ack comes back (the query's single reply, or one Ack on ``cmd/ack`` for a put,
  matched by order and ``request_id``);
* a rejected command changes nothing (same full state, Ack names the state it was in);
* a payload that must be refused is refused; a valid command is accepted exactly when the
  PackML table allows it in the state it arrived in;
* the dispatcher stays alive (a status query answers) and logs no error.

The cell runs with one real worker, the sim robot, slowed down (:data:`FUZZ_OVERRIDES`: the
base takes an hour to park) and the only required role, so a started cycle waits in
``Execute.approaching`` with a real request in flight for as long as the fuzzer likes;
Hold/Suspend/Complete/Stop/Abort/Clear then take the machine through every waiting state of
PackML, each with the robot's real ``stop``.
"""

from cellctl.bench.reliability.fuzz.bench import FUZZ_OVERRIDES, bench_fuzz, run_fuzz, slow_sim_robot
from cellctl.bench.reliability.fuzz.contract import STABLE, FuzzStats, FuzzTarget
from cellctl.bench.reliability.fuzz.generators import CATEGORIES, REJECT, CommandFuzzer, FuzzCase

__all__ = [
    "CATEGORIES",
    "FUZZ_OVERRIDES",
    "REJECT",
    "STABLE",
    "CommandFuzzer",
    "FuzzCase",
    "FuzzStats",
    "FuzzTarget",
    "bench_fuzz",
    "run_fuzz",
    "slow_sim_robot",
]
