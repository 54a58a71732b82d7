"""The HMI in a real browser (Debian's headless Chromium) against a real daemon over real Zenoh."""

from __future__ import annotations

import pytest
from selenium.webdriver.common.by import By

from tests.fakes.workers import FakeCell
from tests.hmi.browser import buttons, login, make_driver, post_from_page, run_cycle_in_browser, wait_until
from tests.hmi.conftest import PASSWORDS, wait_reachable


@pytest.fixture
def driver():
    d = make_driver()
    yield d
    d.quit()


def test_login_command_and_forged_post_in_the_browser(cfg, cell, hmi, client, driver) -> None:
    url = hmi.server.url
    wait_reachable(client)
    # logged out: the diagram shows the state, and there is no command button at all
    driver.get(url + "/")
    wait_until(lambda: driver.find_elements(By.CSS_SELECTOR, "#packml g.current[data-state='Stopped']"), 15,
               "Stopped highlighted")  # fmt: skip
    assert buttons(driver) == []
    assert "Log in" in driver.find_element(By.ID, "cmd-hint").text
    allowed = driver.execute_script(
        "return [...document.querySelectorAll('#packml path.edge.allowed')].map((p) => p.dataset.label);"
    )
    assert allowed == ["reset"]  # the way out of Stopped the cell accepts now (abort is not drawn)
    r = post_from_page(driver, "/api/cmd", {"command": "reset", "nonce": "a" * 20}, csrf=True)
    assert r["status"] == 401

    login(driver, url, "alice", PASSWORDS["alice"])
    wait_until(lambda: buttons(driver) == ["cmd-reset", "cmd-abort"], 15, "the buttons allowed in Stopped")
    # a forged POST from the page without the CSRF token: refused, nothing changes
    r = post_from_page(driver, "/api/cmd", {"command": "reset", "nonce": "b" * 20}, csrf=False)
    assert r["status"] == 403 and "CSRF" in r["body"]["error"]
    assert cell.supervisor.top_state == "Stopped"

    with FakeCell(cfg, dirty_viewpoints={0}):
        cycle_id, views = run_cycle_in_browser(driver, url, "alice", PASSWORDS["alice"])
    assert client.get(f"/api/cycles/{cycle_id}").json()["verdict"] == "dirty"
    assert views == ["thumb dirty", "thumb", "thumb"]

    # logged out again: the buttons go
    driver.get(url + "/")
    wait_until(lambda: buttons(driver), 15, "buttons while logged in")
    driver.find_element(By.ID, "logout-btn").click()
    wait_until(lambda: buttons(driver) == [], 15, "no buttons after logout")


@pytest.mark.slow  # the real sim workers (pybullet, torch) start in minutes and the first cycle plans offline
def test_a_real_sim_cycle_in_the_browser(tmp_path, driver) -> None:
    from argparse import Namespace

    from cellctl.bench.reliability.sim_cell import FAST_SIM, running_sim_cell
    from cellctl.bus.session import private_bus_overrides
    from cellctl.hmi.server import Hmi, HmiServer
    from tests.hmi.conftest import Client, hmi_config

    args = Namespace(config=None, overrides=private_bus_overrides())
    with running_sim_cell(args, "hmi-test", FAST_SIM) as run:
        h = Hmi(run.cfg, hmi_config())
        server = HmiServer(h).start()
        try:
            c = Client(h.hcfg.host, h.hcfg.port)
            wait_reachable(c)
            cycle_id, _ = run_cycle_in_browser(driver, server.url, "alice", PASSWORDS["alice"], cycle_timeout=600)
            res = c.get(f"/api/cycles/{cycle_id}").json()
            assert res["outcome"] == "completed" and res["dirt_map"]
        finally:
            server.stop()
            h.close()
