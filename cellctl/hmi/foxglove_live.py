"""The live Foxglove view (``cellctl hmi --foxglove``): a Foxglove websocket on 127.0.0.1:8765.

It lives in the HMI process, not in the daemon: the daemon stays free of viewers (its import
closure and its dispatcher are what the cycle's timing depends on), and the HMI already tails
the running cycle's MCAP. Every message the log records is forwarded on a channel of the same
topic and schema, so the layout in ``docs/foxglove/`` opens live and recorded data alike. On
top, ``/hmi/scene`` draws what the log does not hold as 3-D primitives: the arm (from the
robot's ``joints`` publication, via the UR10e forward kinematics), the bin mesh at its measured
pose (grey until the dirt map colours it: the supervisor's own ``/scene`` at reporting), the
camera frustum at the last capture pose, and the planned viewpoints.
"""

from __future__ import annotations

import json
import logging
import threading
from typing import Any

import numpy as np

from cellctl.bus import keys, topics
from cellctl.config import CellConfig
from cellctl.hmi.config import FoxgloveConfig
from cellctl.hmi.link import CellView
from cellctl.recording import foxglove as fx
from cellctl.recording.replay import RecordedMessage

__all__ = ["SCENE_TOPIC", "FoxgloveLive"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

SCENE_TOPIC = "/hmi/scene"
_GREY = (0.75, 0.75, 0.78, 0.6)
_BLUE = (0.25, 0.45, 0.95, 1.0)


def _p(x: Any) -> dict[str, float]:
    return {"x": float(x[0]), "y": float(x[1]), "z": float(x[2])}


def _lines(points: list[Any], rgba: tuple[float, ...], thickness: float, kind: int) -> dict[str, Any]:
    """A foxglove LinePrimitive in the scene frame (kind 0 strip, 2 list)."""
    return {
        "type": kind,
        "pose": {"position": _p((0, 0, 0)), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        "thickness": thickness,
        "scale_invariant": False,
        "points": [_p(p) for p in points],
        "color": dict(zip("rgba", rgba, strict=True)),
        "colors": [],
        "indices": [],
    }


def frustum_lines(T_base_cam: np.ndarray, depth: float = 0.25, half_w: float = 0.14, half_h: float = 0.08) -> list:
    """The eight segments (16 points) of a camera frustum of ``depth`` m along the optical +z."""
    corners = [
        T_base_cam @ np.array([sx * half_w, sy * half_h, depth, 1.0]) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    o = T_base_cam[:3, 3]
    pts: list[Any] = []
    for i, c in enumerate(corners):
        pts += [o, c[:3], c[:3], corners[(i + 1) % 4][:3]]
    return pts


class FoxgloveLive:
    """The Foxglove websocket server and its channels (thread-safe; callbacks never block).

    Args:
        link: the HMI's bus link; the arm joints are subscribed through it.
    """

    def __init__(self, cfg: CellConfig, fcfg: FoxgloveConfig, link: CellView) -> None:
        import foxglove

        self._fg = foxglove
        self.cfg = cfg
        self._lock = threading.Lock()
        self._ctx = foxglove.Context()
        self.server = foxglove.start_server(
            name=f"cellctl {cfg.cell_id}", host=fcfg.host, port=fcfg.port, context=self._ctx
        )
        self._channels: dict[tuple[str, str], Any] = {}
        self._catalog: Any = None
        self._bin: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # T_base_bin, vertices, faces
        self._bin_type: str | None = None
        self._camera: np.ndarray | None = None
        self._viewpoints: list[np.ndarray] = []
        self._joints: list[float] | None = None
        link.add_subscriber(keys.robot_joints(cfg.cell_id), self._on_joints)

    @property
    def port(self) -> int:
        return int(self.server.port)

    def _channel(self, topic: str, schema: str, schema_data: bytes | None = None) -> Any:
        ch = self._channels.get((topic, schema))
        if ch is None:
            data = schema_data or _schema_data(schema)
            ch = self._fg.Channel(
                topic,
                schema=self._fg.Schema(name=schema, encoding="jsonschema", data=data),
                message_encoding="json",
                context=self._ctx,
            )
            self._channels[(topic, schema)] = ch
        return ch

    def forward(self, m: RecordedMessage) -> None:
        """Re-publish one message of the cycle log on its own topic; update the scene from it."""
        with self._lock:
            self._channel(m.topic, m.schema).log(m.data, log_time=m.log_time)
            changed = self._fold(m)
            if changed:
                self._publish_scene(m.log_time)

    def _fold(self, m: RecordedMessage) -> bool:
        c = self.cfg.cell_id
        try:
            if m.topic == topics.BIN_IDENTIFICATION:
                self._bin_type = m.json().get("bin_type")
            elif m.topic == topics.BIN_POSE and self._bin_type:
                pose = m.json()["pose"]
                T = _matrix(pose)
                mesh = self._mesh(self._bin_type)
                self._bin = (T, mesh.vertices, mesh.faces) if mesh is not None else None
                return True
            elif m.topic == topics.CAMERA_POSE:
                self._camera = _matrix(m.json()["pose"])
                return True
            elif m.topic == topics.reply(keys.worker_op(c, "planner", "lookup")):
                from cellctl.messages import PoseMsg

                vps = m.json().get("viewpoints") or []
                self._viewpoints = [PoseMsg.model_validate(v["camera_pose"]).matrix() for v in vps]
                return True
        except (ValueError, KeyError, TypeError) as err:
            log.debug("scene: %s ignored: %s", m.topic, err)
        return False

    def _mesh(self, bin_type: str) -> Any:
        try:
            if self._catalog is None:
                from cellctl.geometry.catalog import load_catalog

                self._catalog = load_catalog(self.cfg.path(self.cfg.catalog))
            return self._catalog.load_mesh(bin_type)
        except Exception as err:  # an unknown bin type draws no mesh, never breaks the view
            log.warning("scene: no mesh for bin %r: %s", bin_type, err)
            return None

    def _on_joints(self, sample: Any) -> None:
        try:
            msg = json.loads(sample.payload.to_bytes())
            q = [float(x) for x in msg["position"]][:6]
        except (ValueError, KeyError, TypeError):
            return
        if len(q) != 6:
            return
        with self._lock:
            self._joints = q
            self._publish_scene(None)

    def _publish_scene(self, t_ns: int | None) -> None:
        msg = json.dumps(self.scene(t_ns), separators=(",", ":"))
        self._channel(SCENE_TOPIC, "foxglove.SceneUpdate").log(msg, log_time=t_ns)

    def scene(self, t_ns: int | None = None) -> dict[str, Any]:
        """The ``/hmi/scene`` SceneUpdate from what has been seen so far (bin, viewpoints, arm, frustum)."""
        from cellctl.geometry.robot_model import link_frames

        entities = []
        if self._bin is not None:
            T, v, f = self._bin
            cams = [(Tv, _BLUE, str(i)) for i, Tv in enumerate(self._viewpoints)]
            upd = fx.scene_update("base", T, v, f, np.tile(_GREY, (len(f), 1)), cams, entity_id="bin", t_ns=t_ns)
            entities += upd["entities"]
        extra = fx.scene_update("base", np.eye(4), np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros((0, 4)), [],
                                entity_id="arm", t_ns=t_ns)["entities"][0]  # fmt: skip
        extra["triangles"] = []
        if self._joints is not None:
            origins = link_frames(self._joints)[0][:, :3, 3]
            extra["lines"].append(_lines(list(origins), (0.3, 0.3, 0.3, 1.0), 0.04, 0))
            extra["spheres"] = [
                {"pose": {"position": _p(o), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                 "size": _p((0.07, 0.07, 0.07)), "color": {"r": 0.2, "g": 0.2, "b": 0.2, "a": 1.0}}
                for o in origins
            ]  # fmt: skip
        if self._camera is not None:
            extra["lines"].append(_lines(frustum_lines(self._camera), (0.1, 0.1, 0.1, 1.0), 0.005, 2))
        entities.append(extra)
        return {"deletions": [], "entities": entities}

    def close(self) -> None:
        try:
            self.server.stop()
        except Exception:  # already stopped
            pass


def _schema_data(name: str) -> bytes:
    """The JSON Schema a channel of ``name`` announces (as the cycle log registers it)."""
    from cellctl.messages import MESSAGE_TYPES

    if name in fx.SCHEMAS:
        return fx.schema_bytes(name)
    if name in MESSAGE_TYPES:
        return json.dumps(MESSAGE_TYPES[name].model_json_schema()).encode()
    return b'{"type": "object"}'


def _matrix(pose: dict[str, Any]) -> np.ndarray:
    from cellctl.geometry.transforms import transform_from_pose

    p, q = pose["position"], pose["orientation"]
    return transform_from_pose(((p["x"], p["y"], p["z"]), (q["x"], q["y"], q["z"], q["w"])))
