"""Heat maps on Cycle live and in History: a classifier whose replies carry one, over real Zenoh and HTTP."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.classify.heatmap import encode_heat
from cellctl.messages import ClassifyReply, ClassifyRequest
from tests.fakes.workers import FakeCell
from tests.hmi.conftest import Client, wait_reachable

GRID = 4


@dataclass
class _HeatCell(FakeCell):
    """View 0 is dirty in its top-left patch, view 1 comes without a heat map, view 2 is clean but
    uncertain, and its re-look (the 4th classification) is hot in the bottom-right patch."""

    def _classify(self, req: ClassifyRequest, image: bytes | None) -> ClassifyReply:
        self._guard("classify")
        n = sum(1 for c in self.calls if c == "classify") - 1
        if n == 1:
            return ClassifyReply(label="clean", p_dirty=0.1, model_id="fake-heat")
        heat = np.zeros((GRID, GRID))
        if n == 0:
            heat[0, 0] = 1.0
        if n == 3:
            heat[-1, -1] = 1.0
        return ClassifyReply(
            label="dirty" if n == 0 else "clean",
            p_dirty=0.9 if n == 0 else 0.4,
            uncertain=n == 2,
            model_id="fake-heat",
            heatmap=encode_heat(heat),
            heat_grid=GRID,
        )


def _png(body: bytes) -> np.ndarray:
    assert body[:4] == b"\x89PNG"
    img = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None
    return img


def _hot_corner(img: np.ndarray) -> tuple[float, float]:
    """Mean brightness of the top-left patch and of the bottom-right one."""
    h, w = img.shape[:2]
    ph, pw = h // GRID, w // GRID
    return float(img[:ph, :pw].mean()), float(img[-ph:, -pw:].mean())


def test_heat_maps_show_live_and_in_the_record(cfg, cell, hmi, client: Client) -> None:
    wait_reachable(client)
    assert client.get("/api/live/heatmap").status == 404  # no cycle yet
    client.login("alice")
    with _HeatCell(cfg):
        assert client.cmd("reset").status == 200
        client.wait_state("Idle")
        assert client.cmd("start").status == 200
        client.wait_state("Complete")
    cid = client.get("/api/cycles").json()["cycles"][0]["cycle_id"]

    # Cycle live: the newest heat map (the re-look's, verdict #4), blended over the re-look's own
    # image (the doubles' 64×48 grey), hot where the detector put it
    lv = client.get("/api/live").json()["live"]
    assert lv["cycle_id"] == cid and len(lv["verdicts"]) == 4
    assert lv["heat_map"] == {"view": 4, "seq": 4, "label": "clean", "p_dirty": 0.4}
    live = _png(client.get("/api/live/heatmap").body)
    assert live.shape == (48, 64, 3)
    top_left, bottom_right = _hot_corner(live)
    assert bottom_right > top_left + 60, (top_left, bottom_right)
    page = client.get("/live").body
    assert b'id="lv-heatimg"' in page

    # History: the per-view images carry their view's heat map; the dirty patch is where the detector put it
    rec = client.get(f"/api/cycles/{cid}/record").json()
    # (the CycleResult keeps heat_grid; the maps themselves are the log's /classifier/heatmap images)
    res = client.get(f"/api/cycles/{cid}").json()
    assert [(v["heat_grid"], v["relook_of"]) for v in res["viewpoints"]] == [
        (GRID, None),
        (None, None),
        (GRID, None),
        (GRID, 2),
    ]
    assert [(i["label"], i["heatmap"]) for i in rec["images"]] == [("dirty", 0), ("clean", None), ("clean", 1)]
    dirty = _png(client.get(f"/api/cycles/{cid}/heatmaps/{rec['images'][0]['image']}").body)
    assert dirty.shape == (48, 64, 3)
    hot, cold = _hot_corner(dirty)
    assert hot > cold + 60, (hot, cold)
    plain = _png(client.get(f"/api/cycles/{cid}/images/{rec['images'][0]['image']}").body)
    assert not np.array_equal(plain, dirty)
    none = client.get(f"/api/cycles/{cid}/heatmaps/{rec['images'][1]['image']}")
    assert none.status == 404 and "heat map" in none.json()["error"]
    assert client.get(f"/api/cycles/{cid}/heatmaps/999").status == 404
