"""A day at the live view (issue 31, deliverable 3), in headless Debian Chromium against a served simulated station.

Two sessions one after the other: the card shows an ETA only while a run is under way, 'analysing' between the
end of the measurements and the results, and a new Start clears what belonged to the last session (its events,
faults and results). The page's values are checked against the station's store, not against screenshots.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from playwright.sync_api import Browser, Page, expect

from station.store import SessionStore
from web.config import PanelConfig

SPEED = 100.0
UI_TIMEOUT_MS = 30_000
UNDER_WAY = ("running", "waiting_operator", "pausing", "paused")
PROCEDURE = "integral_precession"

# Every (state, ETA line) pair the card shows, recorded in the page as it changes.
RECORD_ETA = """(card) => {
  window.etaSeen = [];
  const eta = card.querySelector("span.eta");
  const note = () => window.etaSeen.push([card.dataset.state, eta.textContent]);
  new MutationObserver(note).observe(card, {attributes: true, attributeFilter: ['data-state'], subtree: false});
  new MutationObserver(note).observe(eta, {childList: true, characterData: true, subtree: true});
}"""


@pytest.fixture(scope="module")
def site(tmp_path_factory, tools) -> Iterator[dict]:
    home = tmp_path_factory.mktemp("day")
    station = tools.start_station(home / "station", speed=SPEED)
    config = PanelConfig(users=tools.write_users(home / "users.json"), audit_log=home / "audit.jsonl",
                         stations=(station.entry,))  # fmt: skip
    try:
        with tools.serving_panel(config) as url:
            yield {"url": url, "station": station}
    finally:
        tools.stop_process(station.proc)


def operator_page(browser: Browser, url: str, password: str) -> Page:
    page = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
    page.set_default_timeout(UI_TIMEOUT_MS)
    page.goto(f"{url}/login")
    page.fill("input[name=username]", "olga")
    page.fill("input[name=password]", password)
    page.click("button[type=submit]")
    expect(page).to_have_url(f"{url}/")
    return page


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

    first = post(page, "/api/stations/sim/start", {"procedure": PROCEDURE, "params": quick,
                                                   "instrument_serial": "DAY-1"})  # fmt: skip
    assert first["status"] == 200, first
    uid1 = first["body"]["result"]["session_uid"]
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
