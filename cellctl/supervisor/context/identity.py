"""The bin as the cycle found it: the park's approach reply, the identification, the bin's pose."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cellctl.messages import ApproachReply

if TYPE_CHECKING:  # the daemon imports vision lazily: it pulls OpenCV in
    from cellctl.vision.fuse import FusedIdentification
    from cellctl.vision.identify import Identification

__all__ = ["Identity"]


@dataclass
class Identity:
    """Written by approaching and identifying (and reset by the station loop when the base drives)."""

    observation_index: int = 0
    """The observation pose the next approach goes to (identifying moves on to the next after a failure)."""
    identify_attempts: int = 0
    approach: ApproachReply | None = None
    """The approach reply of the current park; None: the base must park again (new station)."""
    identification: Identification | FusedIdentification | None = None
    bin_type: str | None = None
    T_base_bin: np.ndarray | None = None
    """The bin pose in the robot base frame at the current park (measured or carried over)."""
