"""Foxglove well-known JSON schemas (``foxglove.<Type>``) and builders for their messages.

Foxglove/Lichtblick recognise a channel by the schema *name*; the schema text lets any
reader validate the JSON. Times are ``{"sec", "nsec"}``, bytes are base64 strings.
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np

__all__ = ["SCHEMAS", "frame_transform", "log", "pose_in_frame", "scene_update", "stamp"]

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
_POSE = {
    "type": "object",
    "properties": {"position": _VEC3, "orientation": _QUAT},
    "required": ["position", "orientation"],
}
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
    "foxglove.SceneUpdate": _schema(
        "foxglove.SceneUpdate",
        {
            "deletions": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "type": {"type": "integer", "enum": [0, 1]},
                        "id": {"type": "string"},
                    },
                    "required": ["timestamp", "type", "id"],
                },
            },
            "entities": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "frame_id": {"type": "string"},
                        "id": {"type": "string"},
                        "lifetime": _TIME,
                        "frame_locked": {"type": "boolean"},
                        "metadata": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                                "required": ["key", "value"],
                            },
                        },
                        "arrows": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {
                                    "pose": _POSE,
                                    "shaft_length": {"type": "number"},
                                    "shaft_diameter": {"type": "number"},
                                    "head_length": {"type": "number"},
                                    "head_diameter": {"type": "number"},
                                    "color": _COLOR,
                                },
                                "required": [
                                    "pose",
                                    "shaft_length",
                                    "shaft_diameter",
                                    "head_length",
                                    "head_diameter",
                                    "color",
                                ],
                            },
                        },
                        "spheres": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {"pose": _POSE, "size": _VEC3, "color": _COLOR},
                                "required": ["pose", "size", "color"],
                            },
                        },
                        "triangles": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {
                                    "pose": _POSE,
                                    "points": {"type": "array", "items": _VEC3},
                                    "color": _COLOR,
                                    "colors": {"type": "array", "items": _COLOR},
                                    "indices": {"type": "array", "items": {"type": "integer", "minimum": 0}},
                                },
                                "required": ["pose", "points", "color", "colors", "indices"],
                            },
                        },
                        "texts": {
                            "type": "array",
                            "items": {
                                "type": "object",
                                "properties": {
                                    "pose": _POSE,
                                    "billboard": {"type": "boolean"},
                                    "font_size": {"type": "number"},
                                    "scale_invariant": {"type": "boolean"},
                                    "color": _COLOR,
                                    "text": {"type": "string"},
                                },
                                "required": ["pose", "billboard", "font_size", "scale_invariant", "color", "text"],
                            },
                        },
                        "cubes": {"type": "array"},
                        "cylinders": {"type": "array"},
                        "lines": {"type": "array"},
                        "models": {"type": "array"},
                    },
                    "required": [
                        "timestamp",
                        "frame_id",
                        "id",
                        "lifetime",
                        "frame_locked",
                        "metadata",
                        "arrows",
                        "cubes",
                        "spheres",
                        "cylinders",
                        "lines",
                        "triangles",
                        "texts",
                        "models",
                    ],
                },
            },
        },
        ["deletions", "entities"],
    ),
}


def stamp(t_ns: int | None = None) -> dict[str, int]:
    t = time.time_ns() if t_ns is None else t_ns
    return {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}


def log(level: int, message: str, name: str = "cellctl", t_ns: int | None = None) -> dict[str, Any]:
    return {"timestamp": stamp(t_ns), "level": int(level), "message": message, "name": name, "file": "", "line": 0}


def _tq(T: Any) -> tuple[dict[str, float], dict[str, float]]:
    from cellctl.geometry.transforms import pose_from_transform

    p, q = pose_from_transform(np.asarray(T))
    return dict(zip("xyz", p, strict=True)), dict(zip("xyzw", q, strict=True))


def frame_transform(parent: str, child: str, T_parent_child: Any, t_ns: int | None = None) -> dict[str, Any]:
    t, q = _tq(T_parent_child)
    return {
        "timestamp": stamp(t_ns),
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": t,
        "rotation": q,
    }


def pose_in_frame(frame_id: str, T_frame_x: Any, t_ns: int | None = None) -> dict[str, Any]:
    t, q = _tq(T_frame_x)
    return {"timestamp": stamp(t_ns), "frame_id": frame_id, "pose": {"position": t, "orientation": q}}


def schema_bytes(name: str) -> bytes:
    return json.dumps(SCHEMAS[name]).encode()


def _pose(T: Any) -> dict[str, Any]:
    t, q = _tq(T)
    return {"position": t, "orientation": q}


def _colour(rgba: Any) -> dict[str, float]:
    return dict(zip("rgba", (float(x) for x in rgba), strict=True))


def scene_update(
    frame_id: str,
    T_frame_bin: Any,
    vertices: np.ndarray,
    faces: np.ndarray,
    face_rgba: np.ndarray,
    cameras: list[tuple[Any, tuple[float, float, float, float], str]],
    entity_id: str = "inspection",
    t_ns: int | None = None,
) -> dict[str, Any]:
    """A SceneUpdate with the bin mesh (one colour per face) and one arrow per camera pose.

    Args:
        T_frame_bin: (4, 4) bin pose in ``frame_id``.
        vertices, faces: the bin mesh in the bin frame.
        face_rgba: (F, 4) colours in 0..1.
        cameras: ``(T_frame_cam, rgba, label)`` per viewpoint; the arrow points along the optical axis.
    """
    tri = vertices[faces].reshape(-1, 3)
    points = [{"x": float(p[0]), "y": float(p[1]), "z": float(p[2])} for p in np.round(tri, 5)]
    colours = [_colour(c) for c in np.repeat(np.asarray(face_rgba), 3, axis=0)]
    arrows, texts = [], []
    # foxglove arrows point along +x of their pose; the optical axis is the camera's +z
    R_z_to_x = np.array([[0, 0, -1, 0], [0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=float)
    for T, rgba, label in cameras:
        T = np.asarray(T, dtype=float)
        arrows.append(
            {
                "pose": _pose(T @ R_z_to_x),
                "shaft_length": 0.1,
                "shaft_diameter": 0.01,
                "head_length": 0.04,
                "head_diameter": 0.03,
                "color": _colour(rgba),
            }
        )
        texts.append(
            {
                "pose": _pose(T),
                "billboard": True,
                "font_size": 12.0,
                "scale_invariant": True,
                "color": _colour(rgba),
                "text": label,
            }
        )
    ts = stamp(t_ns)
    entity = {
        "timestamp": ts,
        "frame_id": frame_id,
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
        "arrows": arrows,
        "cubes": [],
        "spheres": [],
        "cylinders": [],
        "lines": [],
        "texts": texts,
        "models": [],
        "triangles": [
            {
                "pose": _pose(T_frame_bin),
                "points": points,
                "color": _colour((0.7, 0.7, 0.7, 1.0)),
                "colors": colours,
                "indices": [],
            }
        ],
    }
    return {"deletions": [{"timestamp": ts, "type": 1, "id": ""}], "entities": [entity]}
