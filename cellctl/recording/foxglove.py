"""Foxglove well-known JSON schemas (``foxglove.<Type>``) and builders for their messages.

Foxglove/Lichtblick recognise a channel by the schema *name*; the schema text lets any
reader validate the JSON. Times are ``{"sec", "nsec"}``, bytes are base64 strings.
"""

from __future__ import annotations

import base64
import json
import time
from typing import Any

import numpy as np

__all__ = ["SCHEMAS", "compressed_image", "frame_transform", "log", "pose_in_frame", "stamp"]

_TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
    "required": ["sec", "nsec"],
}
_VEC3 = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in "xyz"},
    "required": ["x", "y", "z"],
}
_QUAT = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in "xyzw"},
    "required": ["x", "y", "z", "w"],
}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}, "required": ["position", "orientation"]}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}, "required": ["r", "g", "b", "a"]}


def _schema(title: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": properties, "required": required}


SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.Log": _schema(
        "foxglove.Log",
        {
            "timestamp": _TIME,
            "level": {"type": "integer", "enum": [0, 1, 2, 3, 4, 5]},
            "message": {"type": "string"},
            "name": {"type": "string"},
            "file": {"type": "string"},
            "line": {"type": "integer", "minimum": 0},
        },
        ["timestamp", "level", "message", "name", "file", "line"],
    ),
    "foxglove.CompressedImage": _schema(
        "foxglove.CompressedImage",
        {
            "timestamp": _TIME,
            "frame_id": {"type": "string"},
            "data": {"type": "string", "contentEncoding": "base64"},
            "format": {"type": "string"},
        },
        ["timestamp", "frame_id", "data", "format"],
    ),
    "foxglove.FrameTransform": _schema(
        "foxglove.FrameTransform",
        {
            "timestamp": _TIME,
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _VEC3,
            "rotation": _QUAT,
        },
        ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
    ),
    "foxglove.PoseInFrame": _schema(
        "foxglove.PoseInFrame",
        {"timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE},
        ["timestamp", "frame_id", "pose"],
    ),
}


def stamp(t_ns: int | None = None) -> dict[str, int]:
    t = time.time_ns() if t_ns is None else t_ns
    return {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}


def log(level: int, message: str, name: str = "cellctl", t_ns: int | None = None) -> dict[str, Any]:
    return {"timestamp": stamp(t_ns), "level": int(level), "message": message, "name": name, "file": "", "line": 0}


def compressed_image(data: bytes, fmt: str, frame_id: str = "camera", t_ns: int | None = None) -> dict[str, Any]:
    return {"timestamp": stamp(t_ns), "frame_id": frame_id, "data": base64.b64encode(data).decode(), "format": fmt}


def _tq(T: Any) -> tuple[dict[str, float], dict[str, float]]:
    from cellctl.geometry.transforms import pose_from_transform

    p, q = pose_from_transform(np.asarray(T))
    return dict(zip("xyz", p, strict=True)), dict(zip("xyzw", q, strict=True))


def frame_transform(parent: str, child: str, T_parent_child: Any, t_ns: int | None = None) -> dict[str, Any]:
    t, q = _tq(T_parent_child)
    return {"timestamp": stamp(t_ns), "parent_frame_id": parent, "child_frame_id": child, "translation": t, "rotation": q}


def pose_in_frame(frame_id: str, T_frame_x: Any, t_ns: int | None = None) -> dict[str, Any]:
    t, q = _tq(T_frame_x)
    return {"timestamp": stamp(t_ns), "frame_id": frame_id, "pose": {"position": t, "orientation": q}}


def schema_bytes(name: str) -> bytes:
    return json.dumps(SCHEMAS[name]).encode()
