"""Every procedure file's session on the deterministic simulated station (discrete-event clock, synchronous
transports; issue 27 d2), run twice with the same seed, the second time beside two busy loops that keep both
cores of a 2-core machine busy: the same stored points, measurements, raw records and analysis results, to the
bit. Session uids, provenance time stamps and wall durations are not part of the promise (content_hash leaves
the provenance out). The shortened sessions of tests/procedure_runs.py, on the station files as shipped."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from busy import busy_loops
from procedure_runs import RUNS, procedure_spec, record, stable

from station.interchange import content_hash
from station.jsonsafe import json_safe
from station.store import SessionStore

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


def _once(name: str, db: Path) -> tuple[str, list, dict, str]:
    uid = record(name, db)
    with SessionStore(db) as store:
        session = store.load_session(uid)
    raw = {pid: {k: np.asarray(v).tobytes() for k, v in vars(streams).items()} for pid, streams in session.raw.items()}
    spec = procedure_spec(name)
    try:
        results = json.dumps(stable(json_safe(spec.analyse(session).results)), sort_keys=True) if spec.analyse else ""
    except ValueError as exc:  # a shortened session may not identify its model: the same refusal both times
        results = f"{type(exc).__name__}: {exc}"
    return content_hash(session), session.points, raw, results


@pytest.mark.parametrize("name", sorted(RUNS))
def test_a_procedures_session_is_the_same_to_the_bit_beside_two_busy_loops(tmp_path: Path, name: str) -> None:
    quiet = _once(name, tmp_path / "quiet.sqlite")
    with busy_loops(2):
        loaded = _once(name, tmp_path / "loaded.sqlite")
    assert loaded[1] == quiet[1]  # every point: stamps, counts, Tm, t1, t2, Np
    assert loaded[0] == quiet[0]  # points, measurements and every measurement array: the same bytes
    assert loaded[2] == quiet[2]  # raw records (pulse edges, grating), byte for byte
    assert loaded[3] == quiet[3]  # every value of the analysis' results
