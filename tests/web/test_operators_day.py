"""An operator's day, in headless Debian Chromium (Playwright), against `station serve` (a simulated station).

Issue 31: on a busy machine a served station faulted itself after every session (heartbeat lost, BusOff), so
Start failed until Reset. Here an operator runs three sessions back to back from the panel's form without a
Reset; the second meets a transient fault (a reply with a wrong checksum from the counter/timer, armed through
the control channel's test hook `inject`) and measures the point again; the third is ended by the emergency stop,
the table comes to rest, and after a Reset a fourth session finishes. A viewer watches all day in a second
browser context: the same state on the page, no enabled control, and every control endpoint answers 403. At
each step the page's values are checked against the station's store, not only against the page.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator

import pytest
from playwright.sync_api import Locator, Page, expect

from station.store import SessionStore

SPEED = 200.0  # station seconds per wall second: a 10-point session takes a few seconds of wall time
DESIGN = {"positions_deg": "0, 72, 144, 216, 288", "freqs_hz": "10", "window_s": "30", "settle_s": "2"}  # 10 points
LONG_DESIGN = DESIGN | {"positions_deg": "0, 36, 72, 108, 144, 180, 216, 252, 288, 324"}  # ended by the e-stop
N_POINTS = 10
PROCEDURE = "integral_precession"
SESSION_S = 120.0  # wall-time bound of one short session, a busy machine included
CONTROL = ("start", "plan", "pause", "resume", "abort", "estop", "reset")

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


@pytest.fixture(scope="module")
def site(tmp_path_factory, tools) -> Iterator[dict]:
    with tools.serving_site(tmp_path_factory.mktemp("day"), SPEED) as served:
        yield served


def stored(site: dict, uid: str) -> dict:
    """The session's row in the served station's store, with its events and results."""
    with SessionStore(site["station"].out / "station.sqlite") as store:
        (row,) = [s for s in store.sessions() if s["uid"] == uid]
        return row | {"events": store.events(uid), "results": {r["method"]: r["result"] for r in store.results(uid)}}


def wait_for_a_point(site: dict, card: Locator, uid: str) -> None:
    """Until session uid has a point in the store and the page shows the session under way."""
    deadline = time.monotonic() + SESSION_S
    while not stored(site, uid)["n_points"]:
        assert time.monotonic() < deadline, f"session {uid} stored no point within {SESSION_S} s"
        time.sleep(0.05)
    expect(card.locator(".session")).to_have_attribute("data-uid", uid)
    expect(card).to_have_attribute("data-state", "running")


def start_from_form(page: Page, serial: str, design: dict) -> str:
    """Fill the start form and press Start; the new session's uid as the form reports it."""
    card = page.locator("article.station[data-station=sim]")
    page.select_option("select[name=procedure]", PROCEDURE)
    for name, value in design.items():
        page.fill(f"input[name={name}]", value)
    page.fill("input[name=instrument_serial]", serial)
    expect(card.locator("button[data-action=start]")).to_be_enabled()
    result = card.locator(".controls .result")
    before = result.inner_text()  # the last session's, if any
    card.locator("button[data-action=start]").click()
    expect(result).not_to_have_text(before)
    expect(result).to_contain_text("started session")
    return re.search(r"started session (\S+):", result.inner_text()).group(1)


def check_finished(site: dict, card: Locator, uid: str) -> dict:
    """The finished session on the page against the store: uid, points, state and the kz coefficient."""
    expect(card).to_have_attribute("data-state", "finished", timeout=SESSION_S * 1000)
    expect(card.locator(".session")).to_have_attribute("data-uid", uid)
    results = card.locator(".results")
    expect(results.locator("h3")).to_have_text(f"Results of session {uid}", timeout=SESSION_S * 1000)
    row = stored(site, uid)
    assert row["status"] == "finished" and row["n_points"] == N_POINTS, row
    expect(card.locator(".points")).to_have_text(str(row["n_points"]))
    expect(card.locator(".counts")).to_have_text(f"{N_POINTS} of {N_POINTS}")
    kz = float(results.locator("tr[data-coefficient=kz] td").nth(1).inner_text())
    assert kz == pytest.approx(row["results"]["integral"]["coefficients"]["kz"]["value"], rel=1e-6)  # 7 digits
    return row


def check_viewer(viewer: Page, operator: Page) -> None:
    """The viewer's card shows what the operator's shows, and offers no control."""
    mine, theirs = (p.locator("article.station[data-station=sim]") for p in (viewer, operator))
    expect(mine).to_have_attribute("data-state", theirs.get_attribute("data-state"))
    for field in (".session", ".counts", ".freq"):
        expect(mine.locator(field)).to_have_text(theirs.locator(field).inner_text())
    expect(mine.locator(".controls")).to_be_hidden()
    expect(mine.locator("button:enabled:visible")).to_have_count(0)


def viewer_refused(viewer: Page) -> dict[str, int]:
    """The status of every control endpoint, asked by the viewer's own page with its CSRF token."""
    return viewer.evaluate(
        """async ([cmds, procedure]) => {
            const me = await (await fetch('/api/me')).json();
            const out = {};
            for (const cmd of cmds) {
              const body = cmd === 'start' || cmd === 'plan'
                ? JSON.stringify({procedure, params: {}}) : undefined;
              const r = await fetch(`/api/stations/sim/${cmd}`, {method: 'POST', body,
                headers: {'X-CSRF-Token': me.csrf, 'Content-Type': 'application/json'}});
              out[cmd] = r.status;
            }
            return out;
        }""",
        [[c for c in CONTROL if c != "plan"], PROCEDURE],  # a dry run moves nothing: a viewer may ask for one
    )


def test_an_operators_day(site, logged_in_page):
    url, station = site["url"], site["station"]
    operator = logged_in_page(url, "olga")
    operator.on("dialog", lambda d: d.accept())  # Reset asks for a confirmation
    viewer = logged_in_page(url, "victor")
    errors: list[str] = []
    for page in (operator, viewer):
        page.on("pageerror", lambda e: errors.append(str(e)))
    card = operator.locator("article.station[data-station=sim]")
    expect(card.locator(".link")).to_have_text("live")
    assert set(viewer_refused(viewer).values()) == {403}

    # Session 1, from the form.
    first = start_from_form(operator, "DAY-1", DESIGN)
    check_finished(site, card, first)
    check_viewer(viewer, operator)

    # Session 2 right away (no Reset): a reply with a wrong checksum; the point is measured again.
    expect(card.locator("button[data-action=reset]")).to_be_disabled()
    second = start_from_form(operator, "DAY-2", DESIGN)
    wait_for_a_point(site, card, second)
    client = station.client()
    try:
        reply = client.request("inject", {"device": "counter", "fault": "crc_error"})
    finally:
        client.close()
    assert reply["ok"], reply
    row = check_finished(site, card, second)
    repeats = [e for e in row["events"] if e["kind"] == "repeat"]
    assert len(repeats) == 1 and "measuring it again" in repeats[0]["message"], row["events"]
    assert any(e["kind"] == "control" and e["message"].startswith("inject by") for e in row["events"]), row["events"]
    for page in (operator, viewer):
        expect(page.locator("article.station[data-station=sim] .faults li").filter(has_text="repeat")).to_have_count(1)
    check_viewer(viewer, operator)

    # Session 3: the emergency stop; the table comes to rest and the session is recorded aborted.
    third = start_from_form(operator, "DAY-3", LONG_DESIGN)
    wait_for_a_point(site, card, third)
    card.locator("button[data-action=estop]").click()
    expect(card).to_have_attribute("data-state", "estopped")
    expect(card.locator(".drive")).to_have_text("EMERGENCY STOP")
    expect(card.locator(".freq")).to_have_text("at rest")
    assert station.wait_until_idle()["freq_hz"] == 0
    row = stored(site, third)
    assert row["status"] == "aborted" and 0 < row["n_points"] < 2 * N_POINTS, row
    assert any("emergency stop" in e["message"] for e in row["events"] if e["kind"] == "abort"), row["events"]
    expect(card.locator(".points")).to_have_text(str(row["n_points"]))
    check_viewer(viewer, operator)

    # Recovery: Reset, then a fourth session finishes.
    expect(card.locator("button[data-action=reset]")).to_be_enabled()
    card.locator("button[data-action=reset]").click()
    expect(card.locator(".controls .result")).to_have_text("reset: sent")
    fourth = start_from_form(operator, "DAY-4", DESIGN)
    check_finished(site, card, fourth)
    check_viewer(viewer, operator)

    assert set(viewer_refused(viewer).values()) == {403}
    with SessionStore(station.out / "station.sqlite") as store:
        assert [s["status"] for s in store.sessions()] == ["finished", "finished", "aborted", "finished"]
    assert not errors, errors
    for page in (operator, viewer):
        page.context.close()
