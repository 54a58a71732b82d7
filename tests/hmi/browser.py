"""Drive the HMI in Debian's headless Chromium (Selenium + /usr/bin/chromedriver, no browser download).

Also a script: ``python -m tests.hmi.browser --url http://127.0.0.1:8080 --user alice --out docs/hmi``
logs in, runs one cycle (Reset, Start) on whatever cell the HMI serves, and saves a screenshot of
every page (how docs/hmi/*.png were made, on a real sim cycle).
"""

from __future__ import annotations

import argparse
import getpass
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


def make_driver(width: int = 1280, height: int = 800) -> Any:
    """A headless Chromium of the panel's size (1280×800 by default)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    missing = [p for p in (CHROMIUM, CHROMEDRIVER) if shutil.which(p) is None]
    if missing:
        raise RuntimeError(f"{missing} not installed: `apt-get install chromium chromium-driver` (make system-deps)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              f"--window-size={width},{height}", "--hide-scrollbars"):  # fmt: skip
        opts.add_argument(a)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)


def wait_until(pred: Callable[[], Any], timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    last_err: Exception | None = None
    while time.monotonic() < deadline:
        try:
            v = pred()
            if v:
                return v
        except Exception as err:  # the element may not exist yet
            last_err = err
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}" + (f" ({last_err})" if last_err else ""))


def text(d: Any, elem_id: str) -> str:
    # read by script: the pages re-render from the event stream, which makes element handles stale
    return d.execute_script("const e = document.getElementById(arguments[0]); return e ? e.textContent : null;",
                            elem_id) or ""  # fmt: skip


def buttons(d: Any) -> list[str]:
    return d.execute_script("return [...document.querySelectorAll('#cmd-buttons button')].map((b) => b.id);")


def natural_width(d: Any, elem_id: str) -> int:
    return d.execute_script("const e = document.getElementById(arguments[0]); return e ? e.naturalWidth : 0;", elem_id)


def login(d: Any, url: str, user: str, password: str) -> None:
    from selenium.webdriver.common.by import By

    d.get(f"{url}/login")
    d.find_element(By.ID, "login-user").send_keys(user)
    d.find_element(By.ID, "login-password").send_keys(password)
    d.find_element(By.ID, "login-submit").click()
    wait_until(lambda: d.current_url.rstrip("/") == url and user in text(d, "who-name"), 15, "the logged-in overview")


def press(d: Any, command: str, timeout: float = 30.0) -> None:
    """Click the Overview's button for ``command`` once the cell allows it, and check it was accepted."""
    from selenium.webdriver.common.by import By

    btn = wait_until(lambda: d.find_element(By.ID, f"cmd-{command}"), timeout, f"the {command!r} button")
    btn.click()
    wait_until(lambda: "accepted" in text(d, "cmd-result") and command in text(d, "cmd-result"), 15,
               f"the Ack of {command!r}")  # fmt: skip


def post_from_page(d: Any, path: str, body: dict[str, Any], csrf: bool) -> dict[str, Any]:
    """A POST made by script in the page (same origin, with its cookie), with or without the CSRF token."""
    js = """
const [path, body, csrf] = arguments;
return (async () => {
  const s = await (await fetch('/api/session')).json();
  const h = {'Content-Type': 'application/json'};
  if (csrf && s.csrf) h['X-CSRF-Token'] = s.csrf;
  const r = await fetch(path, {method: 'POST', headers: h, body: JSON.stringify(body)});
  return {status: r.status, body: await r.json()};
})();
"""
    return d.execute_script(js, path, body, csrf)


def wait_for_heat_maps(d: Any, css: str, timeout: float = 20.0) -> None:
    """Wait (for a screenshot) until the images ``css`` selects have loaded; a cell whose
    classifier sends no heat map has none to wait for, so running out of time is not an error."""
    js = (
        f"return [...document.querySelectorAll('{css}')]"
        ".every((i) => i.classList.contains('hidden') || (i.complete && i.naturalWidth > 0));"
    )
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not d.execute_script(js):
        time.sleep(0.2)


def run_cycle_in_browser(
    d: Any, url: str, user: str, password: str, shots: Path | None = None, cycle_timeout: float = 60.0
) -> tuple[str, list[str]]:
    """Log in, Reset, Start, watch Cycle live reach Complete, open the cycle in History.

    Returns:
        The cycle id and the class names of its per-view figures in History (``thumb dirty`` …).
    """
    from selenium.webdriver.common.by import By

    def shot(name: str) -> None:
        if shots is not None:
            shots.mkdir(parents=True, exist_ok=True)
            time.sleep(0.6)  # let the last update paint
            d.save_screenshot(str(shots / f"{name}.png"))

    login(d, url, user, password)
    wait_until(lambda: d.find_elements(By.CSS_SELECTOR, "#packml g.current"), 15, "the current state in the diagram")
    state = d.find_element(By.CSS_SELECTOR, "#packml g.current").get_attribute("data-state")
    if state == "Aborted":
        press(d, "clear")
        wait_until(lambda: "cmd-reset" in buttons(d), 30, "Stopped after Clear")
    if state not in ("Idle",):
        press(d, "reset")
    wait_until(lambda: "cmd-start" in buttons(d), 60, "Idle: the Start button")
    shot("overview")
    press(d, "start")
    d.get(f"{url}/live")
    if shots is not None:
        rows = "return document.querySelectorAll('#lv-views tr').length;"
        wait_until(lambda: d.execute_script(rows) >= 4, cycle_timeout, "the scan under way (4 verdicts)")
        wait_until(lambda: natural_width(d, "lv-img") > 0, 30,
                   "a live image")  # fmt: skip
        wait_for_heat_maps(d, "#lv-heatimg")
        shot("live_scanning")
    wait_until(lambda: "Complete" in text(d, "lv-outcome"), cycle_timeout, "Cycle live reaching Complete")
    cycle_id = text(d, "lv-cycle")
    shot("live_complete")
    d.get(f"{url}/history")
    wait_until(lambda: d.find_elements(By.CSS_SELECTOR, f"#hist-rows tr[data-cycle='{cycle_id}']"), 15, "History")
    shot("history_list")
    row = wait_until(lambda: d.find_element(By.CSS_SELECTOR, f"#hist-rows tr[data-cycle='{cycle_id}']"), 15,
                     f"cycle {cycle_id} in History")  # fmt: skip
    row.click()
    wait_until(lambda: natural_width(d, "dt-dirt") > 0, 60,
               "the dirt map image")  # fmt: skip
    wait_until(lambda: d.find_elements(By.CSS_SELECTOR, "#dt-views figure img"), 15, "the per-view images")
    views = d.execute_script("return [...document.querySelectorAll('#dt-views figure')].map((f) => f.className);")
    d.execute_script("document.getElementById('detail').scrollIntoView()")
    if shots is not None:
        wait_for_heat_maps(d, "#dt-views img")
    shot("history")
    d.execute_script("document.getElementById('dt-views').previousElementSibling.scrollIntoView()")
    if shots is not None:
        wait_for_heat_maps(d, "#dt-views img")
    shot("history_views")
    d.get(f"{url}/events")
    wait_until(lambda: d.find_elements(By.CSS_SELECTOR, "#events tr"), 15, "the event list")
    shot("events")
    d.get(f"{url}/")
    wait_until(lambda: d.find_elements(By.CSS_SELECTOR, "#packml g.current"), 15, "the diagram")
    shot("overview_complete")
    return cycle_id, views


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default="http://127.0.0.1:8080")
    ap.add_argument("--user", required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--cycle-timeout", type=float, default=600.0)
    ap.add_argument("--phone", action="store_true", help="also a 390×844 screenshot of the Overview")
    a = ap.parse_args()
    password = getpass.getpass(f"password for {a.user}: ")
    d = make_driver()
    try:
        print(run_cycle_in_browser(d, a.url.rstrip("/"), a.user, password, a.out, a.cycle_timeout)[0])
        d.delete_all_cookies()
        d.get(f"{a.url}/")
        time.sleep(1.5)
        d.save_screenshot(str(a.out / "overview_logged_out.png"))
        d.get(f"{a.url}/login")
        time.sleep(0.5)
        d.save_screenshot(str(a.out / "login.png"))
    finally:
        d.quit()
    if a.phone:
        p = make_driver(390, 844)
        try:
            p.get(f"{a.url}/")
            time.sleep(2)
            p.save_screenshot(str(a.out / "overview_phone.png"))
        finally:
            p.quit()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
