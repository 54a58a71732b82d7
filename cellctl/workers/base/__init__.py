"""The mobile base role: park at station k, report pose/state, stop (``base.backend: sim|manual``).

A vendor base plugs in as one more :class:`Base` subclass chosen by ``base.backend``: e.g. a
REST-driven AMR implements :meth:`Base.park` as "post a mission to the dock of station k, poll the
vendor's status endpoint until it reports docked (or an error), with the timeout", :meth:`Base.stop`
as the vendor's pause/cancel call, and :meth:`Base.state` from its pose endpoint (map frame →
cell frame by the station's calibrated dock pose); ``docs/deploy/base.md``.

The supervisor's approaching step parks through it before the arm goes to its observation
pose: station k of the whole-bin plan (station 0 before the plan is known, and in
single-station cycles). A cancelled step (Hold, Stop, Abort) stops the base.
"""

from cellctl.workers.base._port import Base, BaseState, ManualBase, SimBase, make_base

__all__ = ["Base", "BaseState", "ManualBase", "SimBase", "make_base"]
