"""The panel's Start checks the design by the station's dry run (issue 31): a design that cannot work is refused
(422, one line per problem, even confirmed); one with warnings is 409 with the list until the operator confirms."""

from __future__ import annotations

import math
import re

import pytest
from fastapi.testclient import TestClient

from station.twin.plan import equal_angle_positions_deg

PROCEDURE = "integral_precession"
RADIANS = [round(math.radians(d), 3) for d in equal_angle_positions_deg(5)]


@pytest.fixture(scope="module")
def olga(as_user) -> TestClient:
    return as_user("olga")


def body(quick: dict, confirm: bool = False, **params) -> dict:
    return {"procedure": PROCEDURE, "params": quick | params, "instrument_serial": "PIGA-T-31", "confirm": confirm}


def stored(client: TestClient) -> int:
    """Sessions in the station's store, as the panel's history lists them."""
    return len(client.get("/api/sessions", params={"serial": "PIGA-T-31"}).json())


@pytest.mark.parametrize("confirm", [False, True])
def test_a_singular_design_is_refused_before_anything_moves(olga, quick, confirm):
    before = stored(olga)
    reply = olga.post("/api/stations/sim/start", json=body(quick, confirm, positions_deg=[-360, 360, 0]))
    assert reply.status_code == 422, reply.text
    detail = reply.json()["detail"]
    assert "the design is refused before anything moves" in detail and "no point excites ky" in detail
    assert "refused: positions_deg = [-360, 360, 0]" in detail and "fix: positions spread over the circle" in detail
    assert stored(olga) == before and not olga.get("/api/stations/sim/status").json()["busy"]


def test_the_dry_run_shows_a_designs_warnings(olga, quick):
    radians = {"procedure": PROCEDURE, "params": quick | {"positions_deg": RADIANS}}
    reply = olga.post("/api/stations/sim/plan", json=radians)
    assert reply.status_code == 200
    (warning,) = reply.json()["warnings"]
    assert (warning["refusal"], warning["field"], warning["value"]) == (False, "positions_deg", RADIANS)
    assert "look like radians" in warning["reason"] and warning["fix"].startswith("give degrees, e.g. [0, 72")
    shipped = olga.post("/api/stations/sim/plan", json={"procedure": PROCEDURE, "params": quick})
    assert shipped.json()["warnings"] == []


def test_a_design_with_warnings_starts_only_once_confirmed(olga, quick, station):
    before = stored(olga)
    held = olga.post("/api/stations/sim/start", json=body(quick, positions_deg=RADIANS))
    assert held.status_code == 409, held.text
    detail = held.json()["detail"]
    assert [w["field"] for w in detail["warnings"]] == ["positions_deg"]
    assert detail["message"].startswith("confirm to start this design: warning: positions_deg = [0, 1.257")
    assert stored(olga) == before and not olga.get("/api/stations/sim/status").json()["busy"]

    started = olga.post("/api/stations/sim/start", json=body(quick, confirm=True, positions_deg=RADIANS))
    assert started.status_code == 200, started.text
    assert olga.post("/api/stations/sim/abort").status_code == 200
    station.wait_until_idle()  # the aborted session keeps what it measured
    assert stored(olga) == before + 1


def test_the_start_form_lists_the_warnings_and_starts_on_confirm(logged_in_page, served_panel, olga, quick, station):
    from playwright.sync_api import expect

    page = logged_in_page(served_panel, "olga")
    try:
        card = page.locator("article.station[data-station=sim]")
        expect(card.locator("button[data-action=start]")).to_be_enabled()
        for name, value in (quick | {"positions_deg": RADIANS}).items():
            page.fill(f"input[name={name}]", ", ".join(map(str, value)) if isinstance(value, list) else str(value))
        page.click("button[data-action=start]")
        warnings = card.locator(".design-warnings")
        expect(warnings.locator("li")).to_have_text([re.compile(r"^warning: positions_deg = .* look like radians")])
        assert not olga.get("/api/stations/sim/status").json()["busy"]  # held back: nothing started
        warnings.locator("button[data-action=confirm]").click()
        expect(card.locator(".result")).to_contain_text("started session")
        expect(warnings).to_be_empty()
    finally:
        page.context.close()
        olga.post("/api/stations/sim/abort")
        station.wait_until_idle()
