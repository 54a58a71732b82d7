"""The review flow in a real browser (Debian's headless Chromium) against a real daemon over real Zenoh.

A viewer opens the queue and cannot review; an operator confirms the uncertain view clean with a
reason, the ledger records it (user, time), the bank grows by one clean view, and the operator
releases the verdict. The page is saved to ``logs/hmi_review.png`` (the docs' review.png).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from selenium.webdriver.common.by import By

from cellctl.classify.contamination import closeup_steel
from cellctl.classify.heatmap import encode_heat
from cellctl.config import project_root
from cellctl.messages import CaptureReply, CaptureRequest, ClassifyReply, ClassifyRequest
from cellctl.review import LEDGER_NAME
from tests.fakes.workers import CAM_POSE, INTRINSICS
from tests.hmi.browser import login, make_driver, natural_width, post_from_page, text, wait_until
from tests.hmi.conftest import PASSWORDS
from tests.hmi.test_heatmap import GRID, _HeatCell
from tests.hmi.test_review import run_review_cycle

SHOT = project_root() / "logs" / "hmi_review.png"


@dataclass
class _SteelCell(_HeatCell):
    """The review cycle's doubles with something to look at: brushed steel close-ups (256×192), a
    bright streak on the uncertain view (its 3rd view) and a faint heat patch where it lies."""

    def _capture(self, req: CaptureRequest, _: bytes | None) -> tuple[CaptureReply, bytes]:
        self._guard("capture")
        k = sum(c == "capture" for c in self.calls)  # 1: identification, 2-4: the views, 5: the re-look
        img = closeup_steel("external", 192, 256, np.random.default_rng(k))
        if k == 4:
            cv2.line(img, (196, 150), (240, 172), (0.92, 0.9, 0.85), 3)
        ok, buf = cv2.imencode(".png", cv2.cvtColor((img * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
        return CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE), buf.tobytes()

    def _classify(self, req: ClassifyRequest, image: bytes | None) -> ClassifyReply:
        reply = super()._classify(req, image)
        if reply.uncertain:
            heat = np.zeros((GRID, GRID))
            heat[-1, -1] = 0.45
            reply = reply.model_copy(update={"heatmap": encode_heat(heat)})
        return reply


@pytest.fixture
def driver():
    d = make_driver()
    yield d
    d.quit()


def _open_item(d, url: str, item: str) -> None:
    d.get(f"{url}/review")

    def click() -> bool:  # the queue re-renders when the stream brings news: a row found may go stale
        d.find_element(By.CSS_SELECTOR, f"#rv-rows tr[data-item='{item}']").click()
        return True

    wait_until(click, 30, f"{item} queued and clicked")
    wait_until(lambda: text(d, "rv-id") == item, 30, f"item {item} opened")


def test_an_operator_reviews_and_releases_a_viewer_cannot(cfg, cell, hmi, client, driver) -> None:
    url = hmi.server.url
    cid = run_review_cycle(cfg, client, _SteelCell)
    items = client.get("/api/review/queue").json()["items"]
    uv = next(i for i in items if i["why"] == "uncertain")["image"]
    item = f"{cid}/{uv}"

    # a viewer sees the queue and the view, but no decision buttons, and the API refuses the POST
    login(driver, url, "vic", PASSWORDS["vic"])
    _open_item(driver, url, item)
    assert not driver.find_element(By.ID, "rv-form").is_displayed()
    assert "(viewer) cannot review" in text(driver, "rv-hint")
    r = post_from_page(driver, f"/api/review/items/{cid}/{uv}", {"label": "clean", "reason": "looks fine",
                                                                 "nonce": "v" * 20}, csrf=True)  # fmt: skip
    assert r["status"] == 403 and "viewer" in r["body"]["error"]
    driver.delete_all_cookies()

    login(driver, url, "alice", PASSWORDS["alice"])
    _open_item(driver, url, item)
    assert "review required" in text(driver, "rv-release")
    assert "no reference" in text(driver, "rv-ref")
    wait_until(lambda: natural_width(driver, "rv-img") > 0 and natural_width(driver, "rv-heat") > 0, 30,
               "the view and its heat map")  # fmt: skip
    driver.find_element(By.ID, "rv-reason").send_keys("mirror image of the camera, not dirt")
    driver.find_element(By.ID, "rv-clean").click()
    wait_until(lambda: text(driver, "rv-decision").startswith("clean — alice (operator)"), 30, "the decision shown")
    wait_until(lambda: "ready to release" in text(driver, "rv-release"), 30, "the gate open")
    wait_until(lambda: natural_width(driver, "rv-bin") > 0, 60, "the bin picture")
    show_all = "const s = document.getElementById('rv-state'); s.value = 'all'; s.dispatchEvent(new Event('change'));"
    driver.execute_script(show_all)
    wait_until(lambda: driver.find_elements(By.CSS_SELECTOR, f"#rv-rows tr.selected[data-item='{item}']"), 30,
               "the decided view listed under 'all'")  # fmt: skip
    SHOT.parent.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(SHOT))

    ledger = [json.loads(x) for x in (cfg.path(cfg.recording.dir) / LEDGER_NAME).read_text().splitlines()]
    assert [(e["kind"], e["user"], e["image"], e["label"]) for e in ledger] == [("decision", "alice", uv, "clean")]
    assert ledger[0]["time"] and ledger[0]["reason"] == "mirror image of the camera, not dirt"
    assert client.get("/api/review/bank").json()["counts"] == {cfg.planner.surface: {"clean": 1, "dirty": 0}}

    driver.find_element(By.ID, "rv-release-btn").click()
    wait_until(lambda: text(driver, "rv-release").startswith("released: dirty — by alice"), 30, "the release shown")
    rel = client.get(f"/api/cycles/{cid}/release").json()
    assert rel["state"] == "released" and rel["released_by"] == "alice"
    driver.get(f"{url}/history?cycle={cid}")
    wait_until(lambda: text(driver, "dt-release").startswith("released: dirty"), 30, "the release on the cycle page")
    assert client.get("/api/audit").json()["ok"]
