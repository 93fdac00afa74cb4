"""The live view explains itself, on a phone's 360 px screen, in headless Debian Chromium (Playwright).

A simulated station (`station serve`, 100 x real time) and a second configured station that nobody serves;
the panel in a thread. A quick seed-000 session (20 points, 30 s windows): the displacement is a continuous
trace over station time (min/max per pixel column, so the envelope is the table's amplitude), the open window
is plotted, a pause says whether the table is at rest or vibrating (and offers to bring it to rest), a viewer
who connects mid-session is given the session so far, events carry station time and UTC, and the finished
session shows a results card with units and uncertainties. Screenshots go to tests/web/screenshots/.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Browser, Page, expect

from station.store import SessionStore
from station.telemetry import envelope
from web.config import PanelConfig, StationEntry

SCREENSHOTS = Path(__file__).resolve().parent / "screenshots"  # where conftest's browser fixture puts them
PHONE = {"width": 360, "height": 800}
SPEED = 100.0  # the quick session takes about 15 s of wall time
UI_TIMEOUT_MS = 30_000
A0_MM = 30.0  # the crank's amplitude (physics.md: A0 = 0.03 m)
AMPLITUDE_TOL_MM = 1.5  # the grating's noise and a bucket's extreme falling between samples cost far less


def test_envelope_keeps_the_motion_where_a_stride_aliases_it():
    """5 kHz samples of a 10 Hz, 30 mm motion over 100 s: a stride of 2000 samples is 4 periods, so every
    kept sample has the same phase (the flat dashes of the old trace); min/max per bucket keeps +-A0."""
    t = np.arange(0, 100, 1 / 5000)
    z = 0.03 * np.sin(2 * np.pi * 10 * t + 0.3)
    stride = z[:: len(t) // 250]
    assert np.ptp(stride) < 1e-9  # aliased flat
    tt, zz = envelope(t, z, 125)
    assert len(tt) <= 250 and np.all(np.diff(tt) > 0)
    assert zz.max() == pytest.approx(0.03, abs=1e-6) and zz.min() == pytest.approx(-0.03, abs=1e-6)


@pytest.fixture(scope="module")
def site(tmp_path_factory, tools) -> Iterator[dict]:
    home = tmp_path_factory.mktemp("live")
    station = tools.start_station(home / "station", speed=SPEED)
    ghost = StationEntry(name="ghost", title="Station nobody serves", control=f"tcp://127.0.0.1:{tools.free_port()}",
                         telemetry=f"tcp://127.0.0.1:{tools.free_port()}", store=home / "ghost" / "station.sqlite",
                         reports=home / "ghost")  # fmt: skip
    config = PanelConfig(users=tools.write_users(home / "users.json"), audit_log=home / "audit.jsonl",
                         stations=(station.entry, ghost))  # fmt: skip
    try:
        with tools.serving_panel(config) as url:
            yield {"url": url, "station": station, "ghost": ghost}
    finally:
        tools.stop_process(station.proc)


def phone_page(browser: Browser, url: str, name: str, password: str) -> Page:
    page = browser.new_context(viewport=PHONE, device_scale_factor=1).new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    page.goto(f"{url}/login")
    page.fill("input[name=username]", name)
    page.fill("input[name=password]", password)
    page.click("button[type=submit]")
    expect(page).to_have_url(f"{url}/")
    return page


def shot(page: Page, name: str) -> None:
    page.screenshot(path=SCREENSHOTS / f"live-{name}.png", full_page=True)


def fits_the_screen(page: Page) -> None:
    """Nothing wider than the phone: the page does not scroll sideways."""
    width = page.evaluate("document.documentElement.scrollWidth")
    assert width <= PHONE["width"], f"the page is {width} px wide on a {PHONE['width']} px screen"


def wait_until(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"{what} not seen within {timeout_s} s"
        time.sleep(0.05)


def post(page: Page, path: str, body: dict | None = None) -> int:
    return page.evaluate(
        """async ([path, body]) => {
            const me = await (await fetch('/api/me')).json();
            const r = await fetch(path, {method: 'POST', headers: {'X-CSRF-Token': me.csrf,
              'Content-Type': 'application/json'}, body: body === null ? undefined : JSON.stringify(body)});
            return r.status;
        }""",
        [path, body],
    )


def test_a_station_nobody_serves_says_so_with_the_command_to_serve_it(browser, site, passwords):
    page = phone_page(browser, site["url"], "victor", passwords["victor"])
    ghost = page.locator("article.station[data-station=ghost]")
    expect(ghost).to_have_attribute("data-served", "no")
    expect(ghost.locator(".link")).to_have_text("not served")
    expect(ghost.locator(".not-served")).to_contain_text("Station not served")
    command = ghost.locator(".not-served code").inner_text()
    assert command.startswith("station serve --name ghost") and site["ghost"].telemetry in command
    expect(page.locator("article.station[data-station=sim] .link")).to_have_text("live")
    assert page.request.get(f"{site['url']}/api/sessions/no-such-session/certificate").status == 404
    fits_the_screen(page)
    shot(page, "1-not-served-phone")
    page.context.close()


def test_a_session_watched_on_a_phone(browser, site, passwords, quick):
    page = phone_page(browser, site["url"], "olga", passwords["olga"])
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    card = page.locator("article.station[data-station=sim]")
    expect(card.locator(".link")).to_have_text("live")
    status = post(page, "/api/stations/sim/start", {"procedure": "integral_precession", "params": quick,
                                                    "instrument_serial": "LIVE-360"})  # fmt: skip
    assert status == 200
    expect(card).to_have_attribute("data-state", "running")

    # The displacement: a continuous trace over station time whose envelope is the crank's amplitude.
    trace = card.locator(".trace")
    wait_until(lambda: int(trace.get_attribute("data-updates") or 0) >= 3, 20, "three trace updates")
    assert float(trace.get_attribute("data-span-s")) > 0
    assert trace.get_attribute("data-x-axis") == "station time (s)" and "s of station time" in trace.inner_text()
    # 100 s of a 10 Hz, 30 mm motion at 5 kHz in 250 columns (4 periods each, where a stride would alias):
    # every point drawn is a column's min or max, so every one is near +-A0.
    z = page.evaluate(
        """async () => {
            const m = await import('/static/live.js');  // the page's own module instance
            const t = Array.from({length: 500000}, (_, i) => i / 5000);
            const z = t.map((x) => 30 * Math.sin(2 * Math.PI * 10 * x + 0.3));
            const [xs, ys] = m.minMaxPerPixel(t, z, 250);
            return {n: xs.length, ys, sorted: xs.every((x, i) => !i || x >= xs[i - 1])};
        }"""
    )
    assert z["n"] == 500 and z["sorted"]
    assert all(abs(abs(y) - A0_MM) < AMPLITUDE_TOL_MM for y in z["ys"])

    # The open window is plotted; the rates of closed windows accumulate.
    expect(card.locator(".window-plot .plot-title")).to_contain_text("Open window P")
    rates = card.locator(".rates-plot")
    wait_until(lambda: int(rates.get_attribute("data-points")) >= 2, 30, "two closed windows")
    fits_the_screen(page)
    shot(page, "2-running-phone")

    # A viewer who connects now is given the session so far.
    late = phone_page(browser, site["url"], "victor", passwords["victor"])
    late_card = late.locator("article.station[data-station=sim]")
    expect(late_card.locator(".link")).to_have_text("live")
    wait_until(lambda: int(late_card.locator(".rates-plot").get_attribute("data-points")) >= 2, 10,
               "the late viewer's rates")  # fmt: skip
    assert int(late_card.locator(".points").inner_text()) >= 2
    first_events = late_card.locator(".notices li").all_inner_texts()
    assert any("running" in e for e in first_events), first_events  # the session's start, from before it joined
    assert all(re.search(r"t = [\d.e+-]+ s · \d\d:\d\d:\d\d UTC", e) for e in first_events[-3:]), first_events
    shot(late, "3-late-viewer-phone")
    late.context.close()

    # Pause: the card says whether the table is at rest or vibrating, and offers to bring it to rest.
    card.locator("button[data-action=pause]").click()
    expect(card).to_have_attribute("data-state", "paused")
    box = card.locator(".pause-box")
    expect(box).to_be_visible()
    expect(box).to_have_attribute("data-table", re.compile("^(vibrating|at rest)$"))
    table = box.get_attribute("data-table")
    if table == "vibrating":
        expect(box).to_contain_text("still vibrating at")
        expect(box.locator("button[data-action=rest]")).to_be_visible()
    else:
        expect(box).to_contain_text("the table is at rest")
    fits_the_screen(page)
    shot(page, "4-paused-phone")
    card.locator("button[data-action=resume]").click()
    expect(card).to_have_attribute("data-state", "running")
    expect(box).to_be_hidden()

    # The end: a results card with the coefficients, their units and uncertainties, and the report link.
    expect(card).to_have_attribute("data-state", "finished", timeout=90_000)
    results = card.locator(".results")
    expect(results).to_be_visible(timeout=UI_TIMEOUT_MS)
    kz = results.locator("tr[data-coefficient=kz]").first
    expect(kz).to_contain_text("rad/s/g")
    expect(results.locator("tr[data-coefficient=k3]").first).to_contain_text("rad/s/g^3")
    expect(results).to_contain_text("u (k = 1)")
    href = results.locator("a.report-link").get_attribute("href")
    assert re.fullmatch(r"/api/sessions/[A-Za-z0-9_-]+/report", href), href
    uid = href.split("/")[3]
    report = page.request.get(f"{site['url']}{href}")
    assert report.status == 200 and "Coefficients" in report.text()
    certificate = results.locator(
        "a.certificate-link"
    )  # seed 000's analysis issues one (procedures.common.certificate)
    expect(certificate).to_have_attribute("href", f"/api/sessions/{uid}/certificate")
    cert = page.request.get(f"{site['url']}/api/sessions/{uid}/certificate")
    assert cert.status == 200 and "SIMULATED" in cert.text()
    pdf = page.request.get(f"{site['url']}{results.locator('a.certificate-pdf').get_attribute('href')}")
    assert pdf.status == 200 and pdf.body()[:5] == b"%PDF-"
    with SessionStore(site["station"].out / "station.sqlite") as store:  # what the analysis stored
        stored = {r["method"]: r["result"] for r in store.results(uid)}
    value = float(kz.locator("td").nth(1).inner_text())
    assert value == pytest.approx(stored["integral"]["coefficients"]["kz"]["value"], rel=1e-6)  # 7 digits shown
    fits_the_screen(page)
    shot(page, "5-finished-phone")
    assert not errors, errors
    page.context.close()


def test_a_paused_vibrating_table_is_brought_to_rest_from_the_pause_card(browser, site, passwords, quick):
    """Pause while the table vibrates; the card offers to bring it to rest; that aborts the run (the session
    keeps its points) and the table comes to rest."""
    page = phone_page(browser, site["url"], "olga", passwords["olga"])
    page.on("dialog", lambda d: d.accept())
    card = page.locator("article.station[data-station=sim]")
    expect(card.locator(".link")).to_have_text("live")
    site["station"].wait_until_idle()
    params = quick | {"window_s": 60}  # vibration windows long enough to pause in
    assert post(page, "/api/stations/sim/start", {"procedure": "integral_precession", "params": params,
                                                  "instrument_serial": "LIVE-REST"}) == 200  # fmt: skip
    box = card.locator(".pause-box")
    for _ in range(6):  # a pause lands at the next safe point: vibrating, or at rest before a static window
        expect(card).to_have_attribute("data-state", "running")
        card.locator("button[data-action=pause]").click()
        expect(card).to_have_attribute("data-state", "paused")
        expect(box).to_have_attribute("data-table", re.compile("^(vibrating|at rest)$"))
        if box.get_attribute("data-table") == "vibrating":
            break
        card.locator("button[data-action=resume]").click()
    assert box.get_attribute("data-table") == "vibrating", "never paused with the table vibrating"
    shot(page, "6-paused-vibrating-phone")
    box.locator("button[data-action=rest]").click()
    expect(card).to_have_attribute("data-state", "aborted")
    expect(card.locator(".freq")).to_have_text("at rest")
    expect(box).to_be_hidden()
    page.context.close()


NODE = shutil.which("node")


@pytest.mark.skipif(NODE is None, reason="node is not installed")
def test_the_panel_reads_results_as_the_console_does(tmp_path):
    """web/static/common.js coefficientRows against station.coefficients.coefficient_rows on a seed-001 tumble's
    results (lists of blocks, GUM blocks beside plain ones, units from names) and a seed-000 style result."""
    import procedures.tumble.procedure  # noqa: F401 - registers the procedure
    from procedures.tumble.tumble_session import tumble_session
    from station.coefficients import coefficient_rows
    from station.engine.registry import get_procedure
    from station.jsonsafe import json_safe
    from station.twin.pendulous_accelerometer import AccelerometerModel

    session, _ = tumble_session(AccelerometerModel(), [20, 80], 3, 1e-5, np.random.default_rng(3))
    seed001 = json_safe(get_procedure("tumble").analyse(session).results)
    seed000 = {"integral": {"coefficients": {"kz": {"value": 0.56, "sigma": 3e-4}, "ky": {"value": None,
               "sigma": None, "note": "not identifiable"}}, "units": {"kz": "rad/s/g", "ky": "rad/s/g^2"}}}  # fmt: skip
    module = tmp_path / "common.mjs"
    shutil.copy(Path(__file__).resolve().parents[2] / "web" / "static" / "common.js", module)
    script = "\n".join([
        f"import {{ coefficientRows }} from {json.dumps(module.as_uri())};",
        "const doc = JSON.parse((await import('node:fs')).readFileSync(0, 'utf8'));",
        "const rows = coefficientRows(doc).map((r) => [r.result, r.name, r.value, r.u, r.k, r.expanded, r.unit]);",
        "console.log(JSON.stringify(rows));",
    ])  # fmt: skip
    for results in (seed001, seed000):
        done = subprocess.run([NODE, "--input-type=module", "-e", script], input=json.dumps(results),
                              capture_output=True, text=True, timeout=60)  # fmt: skip
        assert done.returncode == 0, done.stderr
        js = json.loads(done.stdout)
        py = [[r.result, r.name, r.value, r.u, r.k, r.expanded, r.unit] for r in coefficient_rows(results)]
        assert [row[:2] + row[6:] for row in js] == [row[:2] + row[6:] for row in py]
        for a, b in zip(js, py, strict=True):
            for x, y in zip(a[2:6], b[2:6], strict=True):
                assert (x is None and y is None) or x == pytest.approx(y, rel=1e-12), (a, b)
