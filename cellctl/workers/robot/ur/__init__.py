"""The UR10e backend of the robot worker: ur-rtde (``rtde_control``, ``rtde_receive``, ``dashboard_client``).

Chosen by ``robot.backend: ur`` in :func:`cellctl.workers.robot.make_robot`. One class,
:class:`UrRobot`, built in layers, one module each:

* :mod:`._rtde`: what the controller's modes and safety bits mean (:func:`classify_fault`);
* :mod:`._calls`: bounded sending calls (ur-rtde blocks for good on a dead link) and their errors;
* :mod:`._connection`: connect, send, (re)start the control program, ``stopJ``, RTDE state reads;
* :mod:`._safety`: the safety monitor, the RTDE watchdog kicks, the fault latch;
* :mod:`._motion`: a planned path as one asynchronous ``moveJ(path)``, watched to its end;
* :mod:`._maintenance`: an operator's explicit commands, ``clear_fault``;
* :mod:`._robot`: :class:`UrRobot`, its state and threads.

Threads: ``ur-safety-monitor`` (RTDE reads only, latches faults), ``ur-watchdog-kick``,
``ur-control-calls`` (the bounded sending calls); every ur-rtde call holds ``UrRobot.io``.
"""

from cellctl.workers.robot.ur._motion import path_deviation
from cellctl.workers.robot.ur._robot import UrRobot
from cellctl.workers.robot.ur._rtde import classify_fault

__all__ = ["UrRobot", "classify_fault", "path_deviation"]
