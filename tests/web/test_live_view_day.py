"""A day at the live view (issue 31, deliverable 3), in headless Debian Chromium against a served simulated station.

Two sessions one after the other: the card shows an ETA only while a run is under way, 'analysing' between the
end of the measurements and the results, and a new Start clears what belonged to the last session (its events,
faults and results). The page's values are checked against the station's store, not against screenshots.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import Browser, Page, expect

from drivers.station import GRATING_RATE_HZ, TRACE_SAMPLES_PER_WALL_S, display_divider
from station.interchange import read_session
from station.store import SessionStore

SPEED = 100.0
UI_TIMEOUT_MS = 30_000
UNDER_WAY = ("running", "waiting_operator", "pausing", "paused")
PROCEDURE = "integral_precession"
A0_MM = 30.0  # the crank's amplitude (physics.md: A0 = 0.03 m)
NODE = shutil.which("node")

# Every (state, ETA line) pair the card shows, recorded in the page as it changes.
RECORD_ETA = """(card) => {
  window.etaSeen = [];
  const eta = card.querySelector("span.eta");
  const note = () => window.etaSeen.push([card.dataset.state, eta.textContent]);
  new MutationObserver(note).observe(card, {attributes: true, attributeFilter: ['data-state'], subtree: false});
  new MutationObserver(note).observe(eta, {childList: true, characterData: true, subtree: true});
}"""


@pytest.mark.parametrize("pace", [None, 10.0, 20.0, 50.0, 100.0, 1000.0])
def test_the_display_trace_walks_through_the_motion_instead_of_strobing_it(pace):
    """A wall second of display samples of every whole-hertz motion spans its whole swing: with a divider of 2000
    (100x) every sample of a 10 Hz motion fell at one phase (the flat line at +24 mm)."""
    d = display_divider(pace, 5000)
    n = int(TRACE_SAMPLES_PER_WALL_S)
    if pace is not None:  # about the display's rate (or the slowest the grating streams), not a flood
        assert GRATING_RATE_HZ * pace / d <= 1.25 * max(n, GRATING_RATE_HZ * pace / 5000)
    t_s = np.arange(n) * d / GRATING_RATE_HZ
    for f_hz in range(1, 11):
        assert np.ptp(np.sin(2 * np.pi * f_hz * t_s + 0.93)) > 1.9, (pace, d, f_hz)
    strobe_t_s = np.arange(n) * 2000 / GRATING_RATE_HZ
    assert np.ptp(np.sin(2 * np.pi * 10 * strobe_t_s + 0.93)) < 1e-9  # the old divider at 100x


@pytest.mark.skipif(NODE is None, reason="node is not installed")
def test_axis_labels_tell_neighbouring_ticks_apart(tmp_path):
    """The mean-rate axis: ticks 1e-7 rad/s apart around 0.5612 rad/s read apart (3 digits made every one 0.561);
    round numbers keep their zeros (num(100, 3) read '1')."""
    module = tmp_path / "common.mjs"
    shutil.copy(Path(__file__).resolve().parents[2] / "web" / "static" / "common.js", module)
    ticks = [0.5612341, 0.5612342, 0.5612343, 0.5612344]
    script = (f"import {{ num, tickLabels }} from {json.dumps(module.as_uri())};\n"
              f"console.log(JSON.stringify([tickLabels(null, {ticks}), tickLabels(null, [-30, -15, 0, 15, 30]), "
              "num(100, 3), num(10, 6), num(0.5, 3), num(2.5e-5, 3)]));")  # fmt: skip
    done = subprocess.run([NODE, "--input-type=module", "-e", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    rates, mm, *nums = json.loads(done.stdout)
    assert [float(x) for x in rates] == pytest.approx(ticks, abs=1e-12) and len(set(rates)) == len(ticks)
    assert mm == ["-30", "-15", "0", "15", "30"]
    assert nums == ["100", "10", "0.5", "2.50e-5"]


@pytest.fixture(scope="module")
def site(tmp_path_factory, tools) -> Iterator[dict]:
    with tools.serving_site(tmp_path_factory.mktemp("day"), SPEED) as served:
        yield served


def operator_page(browser: Browser, url: str, password: str) -> Page:
    page = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    page.goto(f"{url}/login")
    page.fill("input[name=username]", "olga")
    page.fill("input[name=password]", password)
    page.click("button[type=submit]")
    expect(page).to_have_url(f"{url}/")
    return page


def wait_until(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"{what} not seen within {timeout_s} s"
        time.sleep(0.05)


def post(page: Page, path: str, body: dict | None = None) -> dict:
    return page.evaluate(
        """async ([path, body]) => {
            const me = await (await fetch('/api/me')).json();
            const r = await fetch(path, {method: 'POST', headers: {'X-CSRF-Token': me.csrf,
              'Content-Type': 'application/json'}, body: body === null ? undefined : JSON.stringify(body)});
            return {status: r.status, body: await r.json()};
        }""",
        [path, body],
    )


def test_eta_only_while_running_analysing_until_results_and_a_new_start_clears_the_last_session(
    browser, site, passwords, quick
):
    page = operator_page(browser, site["url"], passwords["olga"])
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    card = page.locator("article.station[data-station=sim]")
    expect(card.locator(".link")).to_have_text("live")
    expect(card.locator("span.eta")).to_have_text("no run under way")
    card.evaluate(RECORD_ETA)

    # The form offers what this station runs, in words with units, and names the station file for the rest.
    form = card.locator(".start-form")
    expect(form.locator("option[value=integral_precession]")).to_have_count(1)  # once the library has come
    offered = form.locator("select[name=procedure] option").evaluate_all("(os) => os.map((o) => o.value)")
    assert "integral_precession" in offered and "tumble" not in offered and "rlg_g_sensitivity" not in offered
    expect(form.locator(".elsewhere li[data-procedure=tumble]")).to_contain_text("tumble-sim.toml")
    sigma = form.locator("label", has=page.locator("input[name=zs1_z0_sigma_m]")).locator("span")
    expect(sigma).to_have_text("u(z0) of the Zs1 line fit (m)")

    first = post(page, "/api/stations/sim/start", {"procedure": PROCEDURE, "params": quick,
                                                   "instrument_serial": "DAY-1"})  # fmt: skip
    assert first["status"] == 200, first
    uid1 = first["body"]["result"]["session_uid"]
    trace = card.locator(".trace")  # at 100x too sparse to draw 8-10 Hz: dots that span the swing, said so
    wait_until(lambda: float(trace.get_attribute("data-z-spread-mm") or 0) > A0_MM, 30, "the table's swing")
    assert trace.get_attribute("data-resolved") == "false"
    expect(trace.locator(".plot-title")).to_contain_text("each dot is where the table was")
    expect(card.locator(".results")).to_be_visible(timeout=120_000)
    expect(card).to_have_attribute("data-state", "finished", timeout=UI_TIMEOUT_MS)
    seen = page.evaluate("window.etaSeen")
    states = [s for s, _ in seen]
    assert "analysing" in states, states
    assert states.index("analysing") > max(i for i, s in enumerate(states) if s == "running")
    for state, eta in seen:
        assert ("ETA" in eta) == (state in UNDER_WAY), (state, eta)
    assert any(s == "analysing" and "analysing the session" in eta for s, eta in seen), seen
    with SessionStore(site["station"].out / "station.sqlite") as store:
        n = len(store.load_session(uid1, with_raw=False).points)
    assert n == first["body"]["result"]["plan"]["n_measurements"]
    expect(card.locator("span.eta")).to_have_text(f"finished: 100.0 % ({n} of {n} measurements)")
    expect(card.locator(".notices li").filter(has_text="analysis")).not_to_have_count(0)

    # A run from the panel writes what `station run` writes: the results as JSON and the piga-session/1 export.
    out = site["station"].out
    with SessionStore(out / "station.sqlite") as store:
        stored = {r["method"]: r["result"] for r in store.results(uid1)}
    assert json.loads((out / f"result-{uid1}.json").read_text()) == stored
    exported = read_session(out / f"session-{uid1}")
    assert len(exported.points) == n and exported.provenance["instrument_serial"] == "DAY-1"
    created = exported.provenance["created_utc"]

    # Its page links the report, the certificate (HTML, PDF) and the export, and draws its residuals.
    session_page = page.context.new_page()
    session_page.on("pageerror", lambda e: errors.append(str(e)))
    session_page.goto(f"{site['url']}/sessions/{uid1}")
    links = session_page.locator("#links")
    expect(links.locator("a.certificate-pdf")).to_be_visible()
    for selector, starts in (("#report-link", b"<!DOCTYPE"), ("a.certificate-link", b"<!DOCTYPE"),
                             ("a.certificate-pdf", b"%PDF-"), ("a.export-link", b"PK")):  # fmt: skip
        href = links.locator(selector).get_attribute("href")
        reply = session_page.request.get(f"{site['url']}{href}")
        assert reply.status == 200 and reply.body()[:9].upper().startswith(starts.upper()), (selector, reply.status)
    expect(session_page.locator("#residuals .chart[data-chart=residuals_radps]")).to_be_visible()

    # Its gap diagnosis says what it diagnoses while it runs, and names the session once done.
    session_page.click("#links a[href^='/gap']")
    expect(session_page.locator("#busy")).to_contain_text(f"Diagnosing session {uid1}: ")
    expect(session_page.locator("#verdict")).to_be_visible(timeout=90_000)
    expect(session_page.locator("#busy")).to_be_hidden()
    expect(session_page.locator("#diagnosed")).to_have_attribute("data-uid", uid1)
    expect(session_page.locator("#diagnosed")).to_contain_text(f"DAY-1, created {created[:10]}")
    session_page.close()

    second = post(page, "/api/stations/sim/start", {"procedure": PROCEDURE, "params": quick | {"window_s": 120},
                                                    "instrument_serial": "DAY-2"})  # fmt: skip
    assert second["status"] == 200, second
    uid2 = second["body"]["result"]["session_uid"]
    expect(card.locator(".session a")).to_have_text(uid2)
    expect(card).to_have_attribute("data-state", "running")
    expect(card.locator(".results")).to_be_hidden()
    expect(card.locator(".notices li").filter(has_text="analysis")).to_have_count(0)
    expect(card.locator(".faults li")).to_have_count(0)
    assert uid1 not in card.inner_text()
    assert post(page, "/api/stations/sim/abort")["status"] == 200
    expect(card).to_have_attribute("data-state", "aborted", timeout=UI_TIMEOUT_MS)
    eta = card.locator("span.eta").inner_text()
    assert eta.startswith("aborted: ") and "ETA" not in eta, eta
    site["station"].wait_until_idle()
    time.sleep(0.5)  # a few status beacons after the end: the line stays as it is
    assert card.locator("span.eta").inner_text() == eta
    assert not errors, errors
    page.context.close()
