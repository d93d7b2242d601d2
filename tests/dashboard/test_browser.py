"""``cmrt dashboard`` on the demo's store in a real headless browser (Debian's chromium driven by selenium):
the runs table lists the demo run, the run page draws its plots with no console error, every page is
screenshotted into the test's folder, and the store's bytes are unchanged afterwards."""

import os
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest

from ..service_helpers import FAST_BEND, as_in_a_terminal, cmrt
from .conftest import snapshot

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


def chromium(monkeypatch):
    """Headless chromium with its browser log kept. Missing is a failure, not a skip: `make` installs it."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    assert os.access(CHROMIUM, os.X_OK) and os.access(CHROMEDRIVER, os.X_OK), \
        "apt-get install chromium chromium-driver (make does it as root)"
    monkeypatch.setenv("SE_OFFLINE", "true")  # selenium manager downloads nothing (the driver is named below)
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1280,1800"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)


def serve(store) -> tuple[subprocess.Popen, str]:
    """``cmrt dashboard --port 0`` in a process of its own; its URL from the line it prints."""
    proc = subprocess.Popen([sys.executable, "-m", "cmrt.cli", "dashboard", "--store", str(store), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=as_in_a_terminal)
    line = proc.stdout.readline()
    match = re.search(r"(http://127\.0\.0\.1:\d+)/", line)
    assert match, (line, proc.stderr.read() if proc.poll() is not None else "")
    return proc, match.group(1)


def wait_for(driver, script: str, timeout_s: float = 90.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for: {script}")


def plotted(div: str) -> str:
    """JS: the number of drawn traces in a plotly figure (0 until it is drawn)."""
    return f"return document.querySelectorAll('#{div} .main-svg .scatterlayer .trace').length"


@pytest.mark.slow
def test_the_demo_store_in_a_headless_browser(tmp_path, monkeypatch):
    store = tmp_path / "store" / "cmrt.sqlite"
    store.parent.mkdir()
    cmrt("optimize", *FAST_BEND, "--seed", "1", "--init", "none", "--no-progress", store=store, check=True)  # = demo
    before = snapshot(store)
    proc, url = serve(store)
    driver = chromium(monkeypatch)
    try:
        driver.get(url + "/")
        wait_for(driver, "return document.querySelectorAll('#runs tbody tr').length")
        rows = driver.execute_script("return [...document.querySelectorAll('#runs tbody tr')].map(r => r.innerText)")
        assert len(rows) == 1 and "run 1" in rows[0] and "bend" in rows[0] and "SUCCESS" in rows[0], rows
        driver.save_screenshot(str(tmp_path / "runs.png"))

        driver.find_element("css selector", "#runs tbody a").click()
        for div in ("convergence", "cmrt", "cop"):
            assert wait_for(driver, f"{plotted(div)}") >= 2, div
        assert "SUCCESS" in driver.find_element("id", "summary").text
        assert driver.execute_script("return document.querySelectorAll('#plausibility tr').length") > 3
        assert driver.find_element("id", "store").text == str(store)  # the page names its store
        limits = driver.execute_script("return [...document.querySelectorAll('#plausibility tr')].slice(1)"
                                       ".map(r => [r.cells[0].innerText, r.cells[r.cells.length - 1].innerText])")
        assert len(limits) == 8 and all(limit != "-" for _, limit in limits), limits  # every rule's bound shown
        assert "started cold from the zero CMRT" in driver.find_element("id", "summary").text
        legend = driver.execute_script(
            "return [...document.querySelectorAll('#cop .legendtext')].map(e => e.textContent)")
        assert any(t.startswith("the motion [") for t in legend), legend
        assert "params.clip_s" in driver.find_element("id", "task").text
        driver.save_screenshot(str(tmp_path / "run.png"))

        driver.get(url + "/compare?runs=1")
        assert wait_for(driver, plotted("curves")) >= 1
        driver.save_screenshot(str(tmp_path / "compare.png"))

        driver.get(url + "/runs/99")
        assert "no run 99" in driver.find_element("id", "message").text
        log = driver.get_log("browser")
    finally:
        driver.quit()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    # the one console error is the 404 asked for last; none from the pages that draw
    errors = [e for e in log if e["level"] == "SEVERE" and "/runs/99" not in e["message"]]
    assert errors == []
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert all((tmp_path / f"{page}.png").stat().st_size > 10_000 for page in ("runs", "run", "compare"))
    assert snapshot(store) == before
    if os.environ.get("CMRT_DASHBOARD_SCREENSHOT"):  # docs/dashboard.png: the run page
        shutil.copyfile(tmp_path / "run.png", os.environ["CMRT_DASHBOARD_SCREENSHOT"])


@pytest.mark.slow
def test_the_runs_table_filters_and_sorts(server, monkeypatch):
    driver = chromium(monkeypatch)
    ids = "return [...document.querySelectorAll('#runs tbody tr')].map(r => Number(r.dataset.run))"
    try:
        driver.get(server.url + "/")
        assert wait_for(driver, ids) == [1, 2, 3]
        driver.find_element("css selector", "th[data-key=best_objective]").click()
        assert driver.execute_script(ids) == [2, 1, 3]  # 0.5, 0.7, then the queued run with none
        driver.find_element("css selector", "th[data-key=best_objective]").click()
        assert driver.execute_script(ids) == [1, 2, 3]  # descending; a run without a value stays last
        driver.find_element("id", "filter").send_keys("0.6")
        assert driver.execute_script(ids) == [2]
        driver.find_element("id", "filter").clear()
        driver.find_element("css selector", "#status option[value=queued]").click()
        assert driver.execute_script(ids) == [3]
        assert [e for e in driver.get_log("browser") if e["level"] == "SEVERE"] == []
    finally:
        driver.quit()
