"""End to end in headless Debian Chromium (Playwright for Python, no browser download).

`station serve` (simulated station, 100 x real time) and `station panel` run as
the operator would start them; users are made with `station panel-user add`.
An operator logs in, is stopped by the form on a bad parameter, starts a quick
session, watches the progress bar move and the displacement trace update,
pauses and resumes, and opens the finished session's report; a viewer sees no
controls and is refused by the API, and finds that session in the history.
Screenshots go to tests/web/screenshots/.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx2
import pytest
from playwright.sync_api import Page, expect

SCREENSHOTS = Path(__file__).resolve().parent / "screenshots"  # where conftest's browser fixture puts them
SPEED = 100.0  # the quick session then takes about 12 s of wall time: time to watch, pause and resume
PANEL_START_S = 30.0
UI_TIMEOUT_MS = 30_000
PAUSED_HOLD_S = 1.5


def run_cli(*args: str, env: dict | None = None) -> None:
    subprocess.run(
        [sys.executable, "-m", "station.cli.cli", *args], check=True, env=env, capture_output=True, text=True
    )


def serving(url: str) -> bool:
    try:
        return httpx2.get(url).status_code == 200
    except httpx2.TransportError:
        return False


@pytest.fixture(scope="module")
def panel_url(tmp_path_factory, passwords, tools) -> Iterator[str]:
    """`station serve` and `station panel` (with users from `station panel-user add`), as subprocesses."""
    home = tmp_path_factory.mktemp("e2e")
    station = tools.start_station(home / "station", speed=SPEED)
    config = home / "panel.toml"
    port = tools.free_port()
    config.write_text(
        f'[panel]\nport = {port}\nusers = "{home}/users.json"\naudit_log = "{home}/audit.jsonl"\n\n'
        f'[[stations]]\nname = "{station.name}"\ntitle = "Simulated station"\ncontrol = "{station.control}"\n'
        f'telemetry = "{station.telemetry}"\nstore = "{station.out}/station.sqlite"\nreports = "{station.out}"\n'
    )
    for name, role in (("olga", "operator"), ("victor", "viewer")):
        run_cli("panel-user", "add", name, "--role", role, "--config", str(config), "--password-env", "PW",
                env=os.environ | {"PW": passwords[name]})  # fmt: skip
    panel = subprocess.Popen([sys.executable, "-m", "station.cli.cli", "panel", "--config", str(config)],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        line = panel.stdout.readline()
        assert "panel on http://127.0.0.1:" in line, line + panel.stdout.read()
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + PANEL_START_S
        while not serving(f"{url}/login"):
            assert time.monotonic() < deadline and panel.poll() is None, "the panel did not start serving"
            time.sleep(0.2)
        yield url
    finally:
        tools.stop_process(panel)
        tools.stop_process(station.proc)


def log_in(page: Page, url: str, name: str, password: str) -> None:
    page.goto(f"{url}/")
    expect(page).to_have_url(f"{url}/login")
    page.fill("input[name=username]", name)
    page.fill("input[name=password]", password)
    page.click("button[type=submit]")
    expect(page).to_have_url(f"{url}/")


def shot(page: Page, name: str) -> None:
    page.screenshot(path=SCREENSHOTS / f"{name}.png", full_page=True)


def progress(card) -> float:
    return float(card.locator(".bar[aria-label='session progress']").get_attribute("aria-valuenow"))


def wait_until(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"{what} not seen within {timeout_s} s"
        time.sleep(0.05)


@pytest.mark.slow
def test_operator_runs_a_session_from_the_browser(browser, panel_url, passwords, quick):
    context = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = context.new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    elsewhere: list[str] = []
    page.on("request", lambda r: r.url.startswith(panel_url) or r.url.startswith("data:") or elsewhere.append(r.url))
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))

    log_in(page, panel_url, "olga", passwords["olga"])
    card = page.locator("article.station[data-station=sim]")
    expect(card.locator(".link")).to_have_text("live")
    expect(card.locator("button[data-action=start]")).to_be_enabled()

    # The form refuses a bad parameter before anything is sent.
    page.fill("input[name=window_s]", "0")
    page.click("button[data-action=start]")
    expect(card.locator(".field-error").filter(has_text="window_s = 0")).to_be_visible()
    expect(card.locator(".controls .error[role=alert]").last).to_have_text("fix the marked parameters first")
    shot(page, "1-form-refuses-bad-parameter")

    page.fill("input[name=positions_deg]", ", ".join(map(str, quick["positions_deg"])))
    page.fill("input[name=freqs_hz]", ", ".join(map(str, quick["freqs_hz"])))
    page.fill("input[name=window_s]", str(quick["window_s"]))
    page.fill("input[name=instrument_serial]", "E2E-001")
    page.click("button[data-action=start]")
    expect(card).to_have_attribute("data-state", "running")

    # The progress bar moves and the live trace updates.
    first = progress(card)
    wait_until(lambda: progress(card) > first, 15, "the progress bar moving")
    trace = card.locator(".trace")
    updates = int(trace.get_attribute("data-updates"))
    wait_until(lambda: int(trace.get_attribute("data-updates")) >= updates + 3, 15, "three trace updates")
    assert int(trace.get_attribute("data-points")) > 0
    shot(page, "2-running")

    # Pause: the run stops at its next safe point and the bar stands still; resume.
    card.locator("button[data-action=pause]").click()
    expect(card).to_have_attribute("data-state", "paused")
    held = progress(card)
    time.sleep(PAUSED_HOLD_S)
    assert progress(card) == held
    expect(card.locator("button[data-action=resume]")).to_be_enabled()
    shot(page, "3-paused")
    card.locator("button[data-action=resume]").click()
    expect(card).to_have_attribute("data-state", "running")
    assert progress(card) >= held

    # The session finishes; its page shows the coefficients and opens the report.
    expect(card).to_have_attribute("data-state", "finished", timeout=60_000)
    expect(card.locator(".notices li").filter(has_text="analysis")).to_have_count(1, timeout=UI_TIMEOUT_MS)
    assert progress(card) == 100.0
    shot(page, "4-finished")
    card.locator(".session a").click()
    expect(page.locator("#coefficients table").first).to_be_visible()
    expect(page.locator("#timing tbody tr")).to_have_count(20)
    shot(page, "5-session")
    with context.expect_page() as report_page:
        page.click("#report-link")
    report = report_page.value
    report.wait_for_load_state()
    expect(report.locator("h2").filter(has_text="Coefficients").first).to_be_visible()  # after the provenance
    shot(report, "6-report")

    # The gap diagnosis of the session: verdict, held-out shrink, maps and ranked effects.
    page.click("#links a[href^='/gap']")
    expect(page.locator("#verdict")).to_be_visible(timeout=60_000)
    expect(page.locator("#result table").first).to_contain_text("shrink")
    expect(page.locator("#result table.map")).to_be_visible()
    expect(page.locator("#result table").last.locator("tbody tr")).not_to_have_count(0)
    shot(page, "7-gap")

    assert not elsewhere, f"pages loaded things from elsewhere: {elsewhere}"
    assert not errors, errors
    context.close()


def test_a_viewer_sees_everything_but_may_not_control(browser, panel_url, passwords):
    context = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = context.new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    log_in(page, panel_url, "victor", passwords["victor"])
    card = page.locator("article.station[data-station=sim]")
    expect(card.locator(".link")).to_have_text("live")
    expect(card.locator(".controls")).to_be_hidden()
    expect(page.locator("nav .who")).to_have_text("victor (viewer)")
    status = page.evaluate(
        """async () => {
            const me = await (await fetch('/api/me')).json();
            const r = await fetch('/api/stations/sim/estop', {method: 'POST', headers: {'X-CSRF-Token': me.csrf}});
            return r.status;
        }"""
    )
    assert status == 403
    # The operator's session (the test above) in the history, found by its instrument serial.
    page.goto(f"{panel_url}/history")
    expect(page.locator("#sessions tbody tr")).not_to_have_count(0)
    page.fill("input[name=serial]", "e2e-")
    page.click("#filters button[type=submit]")
    expect(page.locator("#sessions tbody tr")).to_have_count(1)
    expect(page.locator("#sessions tbody tr")).to_contain_text("E2E-001")
    shot(page, "8-viewer-history")
    page.fill("input[name=serial]", "nobody")
    page.click("#filters button[type=submit]")
    expect(page.locator("#sessions")).to_have_text("No session matches.")
    context.close()
