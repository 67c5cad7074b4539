"""nc-web in a real headless browser: Debian's chromium and chromedriver through Selenium, one browser for the
module (each start is costly on a loaded machine), real nc-server and nc-web processes (tests/web/conftest.py).

The login failing, an observer's page without command buttons, values moving while an axis moves, a jog that
moves only while its button is held and stops when the tab holding it closes, the parameter table and the scope
(CSV/PNG export), and every request of the page going to nc-web's own origin (Chromium's performance log).
A screenshot per view goes to build/test-artifacts/web/. Skipped, saying why, without chromium/chromedriver
(``.ci/run`` installs them when it can).
"""
from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path
from typing import Any, Iterator

import pytest

from znc_testing import NcServerProcess, NcTestClient, wait_until
from znc_testing.web_testing import NcWebProcess, claims, start_nc_web

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = ROOT / "build" / "test-artifacts" / "web"
CHROMIUM = os.environ.get("NC_WEB_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
DRIVER = os.environ.get("NC_WEB_CHROMEDRIVER") or shutil.which("chromedriver") or "/usr/bin/chromedriver"

webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed")
if not (os.path.exists(CHROMIUM) and os.path.exists(DRIVER)):
    pytest.skip(f"no headless browser: chromium ({CHROMIUM}) and chromedriver ({DRIVER}) are needed "
                "(apt-get install chromium chromium-driver; .ci/run installs them when apt is usable)",
                allow_module_level=True)

from selenium.common.exceptions import WebDriverException  # noqa: E402
from selenium.webdriver.common.action_chains import ActionChains  # noqa: E402
from selenium.webdriver.common.by import By  # noqa: E402


@pytest.fixture(scope="module")
def web(tmp_path_factory: pytest.TempPathFactory, nc: NcServerProcess, users_file: Path) -> Iterator[NcWebProcess]:
    """nc-web with the default --session-idle (10 s; conftest's is 3 s): a busy browser keeps its login."""
    p = start_nc_web(tmp_path_factory.mktemp("web"), nc.endpoint, ["--users", str(users_file)])
    try:
        yield p
    finally:
        p.stop()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1280,1400", "--no-first-run", "--disable-extensions",
                "--disable-background-networking", "--disable-component-update", "--disable-sync"):
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"performance": "ALL"})
    service = webdriver.ChromeService(executable_path=DRIVER)
    try:
        drv = webdriver.Chrome(options=opts, service=service)
    except WebDriverException as exc:
        pytest.skip(f"chromium did not start: {exc.msg}")
    drv.set_page_load_timeout(120)
    drv.set_script_timeout(60)
    try:
        yield drv
    finally:
        drv.quit()


def shot(drv: Any, name: str) -> None:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    drv.save_screenshot(str(ARTIFACTS / f"{name}.png"))


def log_in(drv: Any, web: NcWebProcess, user: str, password: str) -> None:
    drv.delete_all_cookies()
    drv.get(f"{web.url}/login")
    drv.find_element(By.ID, "user").send_keys(user)
    drv.find_element(By.ID, "password").send_keys(password)
    drv.find_element(By.ID, "login-submit").click()


def cmd_result(drv: Any) -> Any:
    """The page's command result once there is one (a str is "not yet" to wait_until: the text comes in a list);
    an empty one is not yet (a list holding "" was truthy: the wait returned before the reply came)."""
    text = drv.find_element(By.ID, "cmd-result").text
    return [text] if text else "no result yet"


def on_nc_page(drv: Any, web: NcWebProcess, user: str) -> None:
    """Logged in as ``user`` and the page shows the NC's 4 axes with live data."""
    log_in(drv, web, user, f"{user}-pw")
    wait_until(lambda: drv.current_url.endswith("/nc/nc1"), 60, "the NC page after the login")
    wait_until(lambda: len(drv.find_elements(By.CSS_SELECTOR, "#axis-table tbody tr")) == 4, 60, "4 axis rows")
    wait_until(lambda: drv.find_element(By.ID, "alive").get_attribute("class") == "live", 60, "live data")


def cell(drv: Any, axis: int, col: int) -> str:
    return str(drv.find_element(By.ID, f"axis-{axis}").find_elements(By.TAG_NAME, "td")[col].text)


def act_pos(drv: Any, axis: int) -> float:
    return float(cell(drv, axis, 2))


def test_a_wrong_password_is_refused(browser: Any, web: NcWebProcess) -> None:
    log_in(browser, web, "alice", "not-her-password")
    wait_until(lambda: browser.find_elements(By.ID, "login-error"), 60, "the login error")
    assert "Login failed" in browser.find_element(By.ID, "login-error").text
    assert not browser.find_elements(By.ID, "axis-table")
    shot(browser, "login-failed")


def test_an_observer_sees_values_but_no_command_buttons(browser: Any, web: NcWebProcess) -> None:
    on_nc_page(browser, web, "bob")
    for control in ("enable", "jog-plus", "jog-minus", "moveabs", "reset", "stop", "setpos-btn"):
        assert not browser.find_elements(By.ID, control), control
    assert "observer" in browser.find_element(By.ID, "who").text
    shot(browser, "observer")


def test_values_move_and_the_jog_moves_only_while_held(browser: Any, web: NcWebProcess,
                                                       watch: NcTestClient) -> None:
    on_nc_page(browser, web, "alice")
    browser.find_element(By.ID, "axis-1").click()
    wait_until(lambda: "selected" in str(browser.find_element(By.ID, "axis-1").get_attribute("class")), 30,
               "axis 1 selected", interval=0.1)
    browser.find_element(By.ID, "enable").click()
    result = wait_until(lambda: cmd_result(browser), 60, "Power's result", interval=0.1)[0]
    assert result == "accepted"
    wait_until(lambda: claims(watch).get(1) == "web.alice", 30, "axis 1 held by web.alice", interval=0.1)
    wait_until(lambda: cell(browser, 1, 6).startswith("STANDSTILL"), 60, "axis 1 enabled on the page", interval=0.1)
    start = act_pos(browser, 1)
    for field, value in (("target", str(start + 200)), ("velo", "20")):
        el = browser.find_element(By.ID, field)
        el.clear()
        el.send_keys(value)
    browser.execute_script("document.getElementById('cmd-result').textContent = ''")
    browser.find_element(By.ID, "moveabs").click()
    result = wait_until(lambda: cmd_result(browser), 60, "MoveAbsolute's result", interval=0.1)[0]
    assert result == "accepted"
    seen = {act_pos(browser, 1)}
    wait_until(lambda: seen.add(act_pos(browser, 1)) or len(seen) >= 3, 30, "ActPos moving on the page",
               interval=0.05)  # (10 s of motion: several values on a loaded machine)
    assert all(start <= v <= start + 200 for v in seen)
    shot(browser, "operator-moving")
    wait_until(lambda: abs(act_pos(browser, 1) - (start + 200)) < 0.01, 60, "the move done", interval=0.1)

    # jog: moves while the button is held, stands still once released
    browser.find_element(By.ID, "jogvelo").clear()
    browser.find_element(By.ID, "jogvelo").send_keys("50")
    before = act_pos(browser, 1)
    hold = ActionChains(browser).click_and_hold(browser.find_element(By.ID, "jog-plus"))
    hold.perform()
    try:
        wait_until(lambda: act_pos(browser, 1) > before + 5 or f"ActPos {act_pos(browser, 1)}, result "
                   f"{browser.find_element(By.ID, 'cmd-result').text!r}", 30, "the axis jogging while held",
                   interval=0.05)
        time.sleep(1.0)  # still held: still moving (asserted below)
        mid = act_pos(browser, 1)
        wait_until(lambda: act_pos(browser, 1) > mid + 5, 30, "still jogging after 1 s held")
        shot(browser, "operator-jogging")
    finally:
        ActionChains(browser).release().perform()
    wait_until(lambda: abs(float(cell(browser, 1, 4))) < 1e-3, 30, "ActVelo 0 after the release", interval=0.1)
    stopped = act_pos(browser, 1)
    time.sleep(1.0)
    assert act_pos(browser, 1) == pytest.approx(stopped, abs=1e-6)  # released: it stays


def test_closing_the_tab_of_a_held_jog_stops_the_axis(browser: Any, web: NcWebProcess, watch: NcTestClient) -> None:
    main = browser.current_window_handle
    browser.switch_to.new_window("tab")
    try:
        browser.get(f"{web.url}/nc/nc1")  # the same login (cookie)
        wait_until(lambda: len(browser.find_elements(By.CSS_SELECTOR, "#axis-table tbody tr")) == 4, 60, "the page")
        browser.find_element(By.ID, "axis-1").click()
        wait_until(lambda: watch.nctoplc(1) is not None, 20, "NCTOPLC of axis 1")
        ActionChains(browser).click_and_hold(browser.find_element(By.ID, "jog-minus")).perform()
        wait_until(lambda: float(watch.nctoplc(1)["SetVelo"]) < -1.0, 30, "the jog running")  # type: ignore[index]
    finally:
        browser.close()  # the tab goes with the button still held: its WebSocket closes
        browser.switch_to.window(main)
    t0 = time.monotonic()
    wait_until(lambda: float(watch.nctoplc(1)["SetVelo"]) == 0.0, 30, "the axis stopped")  # type: ignore[index]
    print(f"stopped {1000 * (time.monotonic() - t0):.0f} ms after the tab closed (incl. deceleration)")
    browser.find_element(By.ID, "disable").click()
    wait_until(lambda: 1 not in claims(watch), 30, "axis 1 released")


def test_parameters_and_scope_of_an_engineer(browser: Any, web: NcWebProcess) -> None:
    on_nc_page(browser, web, "eve")
    browser.find_element(By.ID, "axis-2").click()

    def velo_max() -> tuple[float] | str:
        # under load the page's first read may find the NC's door not connected yet (the table stays empty and
        # the heading says why): read again until the value is there
        rows = browser.find_elements(By.ID, "param-AxisVeloMax")
        text = str(rows[0].find_elements(By.TAG_NAME, "td")[2].text) if rows else ""
        if not text:
            browser.find_element(By.ID, "param-read").click()
            return "no value yet: " + str(browser.find_element(By.ID, "param-axis").text)
        return (float(text),)
    (value,) = wait_until(velo_max, 60, "AxisVeloMax in the parameter table", interval=0.5)
    assert value > 0
    row = browser.find_element(By.ID, "param-AxisVeloMax")
    assert row.find_elements(By.TAG_NAME, "button")  # an engineer may write
    assert browser.find_elements(By.ID, "setpos-btn")
    browser.execute_script("document.getElementById('params').scrollIntoView()")
    shot(browser, "engineer-parameters")
    browser.execute_script("document.getElementById('scope').scrollIntoView()")
    wait_until(lambda: browser.execute_script("return window.ncweb.frames") > 20, 30, "frames for the scope")
    rows = browser.execute_script("return window.ncweb.exportCsv()")
    assert rows > 20
    png = browser.execute_script("return document.getElementById('scope-canvas').toDataURL('image/png')")
    assert png.startswith("data:image/png;base64,") and len(png) > 1000
    browser.find_element(By.ID, "scope-pause").click()
    n = browser.execute_script("return window.ncweb.frames")
    assert browser.find_element(By.ID, "scope-pause").text == "Run"
    browser.find_element(By.ID, "zoom-in").click()
    assert "5 s" in browser.find_element(By.ID, "scope-window").text
    wait_until(lambda: browser.execute_script("return window.ncweb.frames") > n + 5, 30, "frames while paused")
    shot(browser, "engineer-scope")


def test_the_page_requests_nothing_outside_its_origin(browser: Any, web: NcWebProcess) -> None:
    browser.get_log("performance")  # (drop what came before)
    browser.get(f"{web.url}/nc/nc1")
    wait_until(lambda: browser.find_element(By.ID, "alive").get_attribute("class") == "live", 60, "live data")
    urls = set()
    for entry in browser.get_log("performance"):
        msg = json.loads(entry["message"])["message"]
        if msg["method"] in ("Network.requestWillBeSent", "Network.webSocketCreated"):
            urls.add(msg["params"].get("request", {}).get("url") or msg["params"].get("url"))
    origin = web.url.split("://", 1)[1]
    assert urls, "no request seen in the performance log"
    outside = [u for u in urls if u.split("://", 1)[-1].split("/", 1)[0] != origin and not u.startswith("data:")]
    assert not outside, outside
    assert any(u.startswith("ws://") for u in urls) and any(u.endswith("/static/app.js") for u in urls)
