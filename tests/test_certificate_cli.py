"""`station certificate` (issue 32, deliverable 3): the certificate of an imported session, issued by the same
analysis as after `station run`, for a stored uid or an exported directory; clear errors for a missing one."""

import json

import pytest

from station.cli.cli import main
from station.interchange import content_hash, read_session, write_session
from station.provenance import make_provenance
from station.store import SessionStore
from station.twin.config import TwinConfig
from station.twin.plan import multiposition_plan
from station.twin.session_sim import simulate_session


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    session = simulate_session(multiposition_plan([0.0, 60.0, 120.0, 180.0, 240.0, 300.0], [8.0, 10.0],
                                                  window_s=20.0), TwinConfig(), seed=4)  # fmt: skip
    session.provenance = make_provenance(station_id="twin", simulated=True, seed=4)  # as `station simulate` writes
    return write_session(session, tmp_path_factory.mktemp("cert") / "s")


def test_certificate_of_an_imported_session_matches_identify(tmp_path, session_dir):
    first, second = tmp_path / "first.sqlite", tmp_path / "second.sqlite"
    assert main(["import", str(session_dir), "--db", str(first)]) == 0
    with SessionStore(first) as store:
        (uid,) = [s["uid"] for s in store.sessions()]
    exported = tmp_path / "exported"
    assert main(["export", uid, str(exported), "--db", str(first)]) == 0
    assert main(["import", str(exported), "--db", str(second)]) == 0  # a new store: the export's uid is kept
    out = tmp_path / "cert"
    assert main(["certificate", uid, "--db", str(second), "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {f"certificate-{uid}.{x}" for x in ("html", "pdf", "json")}
    assert (out / f"certificate-{uid}.pdf").read_bytes().startswith(b"%PDF")
    assert uid in (out / f"certificate-{uid}.html").read_text()
    cert = json.loads((out / f"certificate-{uid}.json").read_text())
    identified = tmp_path / "identified.json"
    assert main(["identify", str(exported), "--json", str(identified)]) == 0
    ident = json.loads(identified.read_text())["coefficients"]
    certified = cert["results"]["integral"]["coefficients"]
    for name, c in ident.items():
        for field in ("value", "standard_uncertainty", "coverage_factor", "expanded_uncertainty"):
            assert certified[name][field] == c[field], (name, field)


def test_certificate_of_an_exported_directory(tmp_path, session_dir):
    """A directory never stored has no store uid: its certificate is named and numbered by its content hash, the
    same for the same directory, another for another session (never "CERT-not recorded" for every one)."""
    uid = f"sha256-{content_hash(read_session(session_dir))[:16]}"
    for out in (tmp_path / "c", tmp_path / "again"):
        assert main(["certificate", str(session_dir), "--out", str(out)]) == 0
        assert {p.name for p in out.iterdir()} == {f"certificate-{uid}.{x}" for x in ("html", "pdf", "json")}
        html = (out / f"certificate-{uid}.html").read_text()
        assert f"CERT-{uid}" in html and "not recorded" not in html.split("calibration session", 1)[1][:200]
        assert json.loads((out / f"certificate-{uid}.json").read_text())["session_uid"] == uid
    other = simulate_session(multiposition_plan([0.0, 90.0, 180.0, 270.0], [8.0, 10.0], window_s=20.0), TwinConfig(),
                             seed=5)  # fmt: skip
    other.provenance = make_provenance(station_id="twin", simulated=True, seed=5)
    other_dir = write_session(other, tmp_path / "other")
    assert main(["certificate", str(other_dir), "--out", str(tmp_path / "o")]) == 0
    (named,) = {p.stem for p in (tmp_path / "o").iterdir()}
    assert named.startswith("certificate-sha256-") and named != f"certificate-{uid}"


def test_a_missing_session_is_one_clear_line(tmp_path, capsys, session_dir):
    assert main(["certificate", "no-such-session", "--out", str(tmp_path / "c")]) == 2
    assert "no session directory there" in capsys.readouterr().err
    db = tmp_path / "db.sqlite"
    assert main(["import", str(session_dir), "--db", str(db)]) == 0
    assert main(["certificate", "nouid", "--db", str(db), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nouid: no such session directory, nor a session of that uid" in err[0]
    assert main(["certificate", "nouid", "--db", str(tmp_path / "none.sqlite")]) == 2
    assert "no session store there" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()
