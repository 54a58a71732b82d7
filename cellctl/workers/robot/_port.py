"""The robot role's interface: every backend (sim today, a UR driver later) implements it."""

from __future__ import annotations

import abc

from cellctl.messages import ApproachReply, ApproachRequest, MoveReply, MoveRequest, RobotState, WashReply, WashRequest

__all__ = ["Robot"]


class Robot(abc.ABC):
    """A mobile manipulator with an eye-in-hand camera.

    Poses on this interface are in the robot **base** frame (see
    :mod:`cellctl.geometry.robot_model`); joints in radians. Motions block until done.
    Refusals raise :class:`~cellctl.errors.RobotError` with the reason.
    """

    @abc.abstractmethod
    def approach(self, req: ApproachRequest) -> ApproachReply:
        """Park beside the bin (if ``req.park``) and go to observation pose ``req.observation_index``."""

    @abc.abstractmethod
    def move(self, req: MoveRequest) -> MoveReply:
        """Move to joints or to a camera pose along a collision-free path; blocks until settled."""

    def wash(self, req: WashRequest) -> WashReply:
        """Run the nozzle's wash sweeps (joint waypoints, continuous); blocks until done.

        A backend without a nozzle refuses (RobotError).
        """
        from cellctl.errors import RobotError

        raise RobotError(f"the {type(self).__name__} backend has no washing nozzle: cannot run the sweeps")

    @abc.abstractmethod
    def state(self) -> RobotState:
        """Joints, flange and camera pose now (never blocks on a motion)."""

    @abc.abstractmethod
    def stop(self, reason: str) -> None:
        """Stop any motion now; the interrupted motion raises RobotError."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the hardware/sim."""

    def __enter__(self) -> Robot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
