"""`station gap` from a directory or our own store: JSON with the required keys, a self-contained HTML, a twin."""

from __future__ import annotations

import json
import re

import pytest

from station.cli.cli import main
from station.interchange import write_session
from station.store import SessionStore
from station.twin.config import TwinConfig

REQUIRED = {"verdict", "effects", "candidates", "gap_before", "gap_after", "where", "identifiability"}
CANDIDATE_KEYS = {"name", "parameters", "uncertainty", "evidence", "heldout_shrink", "identifiable"}
SESSION = ("effect", "cross_coupling", 15.0, 3)


@pytest.fixture(scope="module")
def outputs(seed000_session, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gap")
    write_session(seed000_session(*SESSION)[0], tmp / "session")
    args = ["gap", str(tmp / "session"), "--json", str(tmp / "g.json"), "--html", str(tmp / "g.html")]
    assert main([*args, "--twin-out", str(tmp / "twin.toml")]) == 0
    return tmp


def test_the_json_holds_the_required_keys(outputs):
    doc = json.loads((outputs / "g.json").read_text())
    assert set(doc) >= REQUIRED
    assert doc["verdict"] == "explained" and doc["effects"] == ["cross_coupling"]
    assert len(doc["candidates"]) == 11  # every effect of physics.md's table
    for c in doc["candidates"]:
        assert set(c) >= CANDIDATE_KEYS, c["name"]
    top = doc["candidates"][0]
    assert top["name"] == "cross_coupling" and set(top["parameters"]) == set(top["uncertainty"]) == {"kip"}
    assert top["heldout_shrink"] >= 0.8
    for gap in (doc["gap_before"], doc["gap_after"]):
        assert "mean z^2 - 1" in gap["metric"] and gap["rate_excess_rms_radps"] is not None
    assert doc["where"]["summary"] and doc["where"]["maps"]["by_position"]


def test_the_html_is_self_contained_with_its_maps(outputs):
    html = (outputs / "g.html").read_text()
    assert html.startswith("<!doctype html>") and html.rstrip().endswith("</html>")
    assert "http://" not in html and "https://" not in html
    assert not re.search(r"<(script|link|iframe)\b", html)
    # the only references are inside the page: fragments and data: URIs of the maps' rasters
    assert not re.search(r"""(?:src|href)\s*=\s*["'](?!#|data:)""", html)
    assert html.count("<svg") >= 2
    assert "Verdict: <span class=ok>explained</span>" in html and "cross_coupling" in html


def test_the_twin_out_has_the_effect_switched_on_and_loads(outputs):
    twin = TwinConfig.from_toml(outputs / "twin.toml")
    doc = json.loads((outputs / "g.json").read_text())
    assert twin.effects["cross_coupling"]["kip"] == pytest.approx(doc["candidates"][0]["parameters"]["kip"])
    assert twin.to_dict() == doc["twin_config"]


def test_a_session_of_our_own_store(seed000_session, outputs, tmp_path):
    session = seed000_session(*SESSION)[0]
    with SessionStore(tmp_path / "store.sqlite") as store:
        uid = store.create_session(session.station, "test")
        for p in session.points:
            store.add_point(uid, p)
    args = ["gap", "--db", str(tmp_path / "store.sqlite"), uid, "--json", str(tmp_path / "g.json"), "--no-suggest"]
    assert main(args) == 0
    from_store = json.loads((tmp_path / "g.json").read_text())
    from_dir = json.loads((outputs / "g.json").read_text())
    assert from_store["verdict"] == from_dir["verdict"]
    assert from_store["candidates"][0]["parameters"] == pytest.approx(from_dir["candidates"][0]["parameters"])


def test_the_twin_out_used_as_twin_leaves_no_gap(outputs):
    args = ["gap", str(outputs / "session"), "--twin", str(outputs / "twin.toml")]
    args += ["--json", str(outputs / "again.json")]
    assert main([*args, "--no-suggest"]) == 0
    assert json.loads((outputs / "again.json").read_text())["verdict"] == "no_gap"


def test_without_json_a_short_human_summary_is_printed(outputs, capsys):
    """Verdict, the effect with its parameter and uncertainty, the shrink, what this design cannot test."""
    capsys.readouterr()
    assert main(["gap", str(outputs / "session"), "--no-suggest"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0] == "verdict: explained"
    doc = json.loads((outputs / "g.json").read_text())
    kip, sd = doc["candidates"][0]["parameters"]["kip"], doc["candidates"][0]["uncertainty"]["kip"]
    assert f"cross_coupling: kip = {kip:.4g} ± {sd:.2g} rad/s/g^2" in out
    assert "held-out gap (mean z^2 - 1): before" in out and "shrink" in out
    assert "noise: sigma0" in out and len(lines) < 15


def test_the_summary_names_what_the_design_cannot_test_and_the_points_that_would(seed000_report):
    from station.gap.api import summary_text

    rep = seed000_report("effect", "mount_misalignment", 15.0, 3, suggest=True)
    text = summary_text(rep)
    assert text.startswith("verdict: cannot_tell")
    assert "mount_misalignment" in text and "index_harmonics" in text
