"""MCAP topic names of a cycle log: every channel a cycle writes, in one place.

Beside :mod:`cellctl.bus.keys` because half of them *are* bus keys: a cycle log records the
bus traffic it took part in on the key it travelled on —

* PackML commands on ``keys.cmd(cell)``, Acks on ``keys.cmd_ack(cell)``, Status on
  ``keys.status(cell)``, the CycleResult on ``keys.result(cell)`` (schema = the message type);
* every worker request on ``<key>/request`` and its reply (or ErrorReply) on
  ``<key>/reply`` (:func:`request`, :func:`reply`, :func:`exchange_of`) —

and the rest are the cycle's own observations (images, poses, identification, events), fixed
names below, chosen to match Foxglove's conventions (``/tf``, ``foxglove.*`` schemas).

These strings are the on-disk layout of every recorded log: ``cellctl replay``, ``report``,
``audit`` and the HMI find records by them, and logs recorded before must keep replaying.
Never rename one; add a new topic instead (``tests/bus/test_topics.py`` pins them).
"""

from __future__ import annotations

from typing import Literal

__all__ = [
    "BIN_IDENTIFICATION",
    "BIN_IDENTIFICATION_FUSED",
    "BIN_POSE",
    "CAMERA_IMAGE",
    "CAMERA_POSE",
    "EVENTS",
    "FIXED_TOPICS",
    "HEATMAP",
    "REPLY_SUFFIX",
    "REQUEST_SUFFIX",
    "SCENE",
    "TF",
    "exchange_of",
    "reply",
    "request",
]

CAMERA_IMAGE = "/camera/image"
"""Every captured image (``foxglove.CompressedImage``: identification views and viewpoints)."""
CAMERA_POSE = "/camera/pose"
"""The camera pose of the scan capture just before it (``foxglove.PoseInFrame``, robot base frame)."""
BIN_IDENTIFICATION = "/bin/identification"
"""One identification result per view (``cellctl.Identification``)."""
BIN_IDENTIFICATION_FUSED = "/bin/identification_fused"
"""The fused estimate when several views were identified (``cellctl.FusedIdentification``)."""
BIN_POSE = "/bin/pose"
"""The bin pose the cycle went on with (``foxglove.PoseInFrame``, robot base frame)."""
TF = "/tf"
"""``base → bin`` (``foxglove.FrameTransform``)."""
SCENE = "/scene"
"""The dirt map as a 3D scene (``foxglove.SceneUpdate``)."""
EVENTS = "/events"
"""Supervisor events of the cycle (``foxglove.Log``)."""
HEATMAP = "/classifier/heatmap"
"""Per-patch dirt probability of each classified view, colour-coded (``foxglove.CompressedImage``)."""
WASH_PLAN = "/wash/plan"
"""Each wash-and-verify round's wash plan: sweeps, targets, unwashable pieces, times (``cellctl.WashPlan``)."""
WASH_ROUND = "/wash/round"
"""Each wash-and-verify round's record after re-inspection (``cellctl.WashRound``)."""
REFERENCES = "/references"
"""What a cycle judged against (``cellctl.References``: decision path per surface, reference set version); a
commissioning cycle's also carries the reference set's manifest and its sha256 (the audit checks the set by it)."""

FIXED_TOPICS = (
    CAMERA_IMAGE,
    CAMERA_POSE,
    BIN_IDENTIFICATION,
    BIN_IDENTIFICATION_FUSED,
    BIN_POSE,
    TF,
    SCENE,
    EVENTS,
    HEATMAP,
    WASH_PLAN,
    WASH_ROUND,
    REFERENCES,
)
"""Every topic whose name does not derive from a bus key."""

REQUEST_SUFFIX = "/request"
REPLY_SUFFIX = "/reply"


def request(key: str) -> str:
    """The topic a worker request sent on bus key ``key`` is recorded on."""
    return key + REQUEST_SUFFIX


def reply(key: str) -> str:
    """The topic the reply (or ErrorReply) to a request on ``key`` is recorded on."""
    return key + REPLY_SUFFIX


def exchange_of(topic: str) -> tuple[str, Literal["request", "reply"]] | None:
    """``(bus key, "request" | "reply")`` for a worker-exchange topic, None for any other topic."""
    if topic.endswith(REQUEST_SUFFIX):
        return topic[: -len(REQUEST_SUFFIX)], "request"
    if topic.endswith(REPLY_SUFFIX):
        return topic[: -len(REPLY_SUFFIX)], "reply"
    return None
