"""The deterministic simulated station (drivers.station.simulated_station(deterministic=True): the discrete-event
clock of station.event_clock, the station_sim CAN interface, sim:// serial lines): a short session run twice,
the second time beside two busy loops that keep both cores of a 2-core machine busy, stores the same points,
raw records and results, to the bit (session uids, time stamps of the provenance and wall durations aside)."""

from __future__ import annotations

import pytest
from busy import busy_loops
from procedure_runs import stable

from station.engine.runner import State
from station.interchange import content_hash

pytestmark = pytest.mark.timeout(180)

# Each a few seconds of CPU. The integral session: 2 positions at 10 Hz, each with its static point, every edge
# of the pulse record kept (4 points, 90 s of station time; 4 points cannot identify its 6 parameters, so its
# analysis reports that instead of results). The self-alignment: 2 static points and the eq. 26 result.
SESSIONS = {
    "integral": ("integral_precession",
                 {"positions_deg": [0, 180], "freqs_hz": [10], "window_s": 5, "settle_s": 1, "raw": True}),
    "alignment": ("integral_precession.self_alignment", {"positions_deg": [0, 180], "window_s": 10}),
}  # fmt: skip


@pytest.mark.parametrize("name", SESSIONS)
def test_a_session_is_the_same_to_the_bit_beside_two_busy_loops(make_rig, tmp_path, name) -> None:
    procedure, params = SESSIONS[name]

    def once(db_name: str) -> tuple[str, list, list, list]:
        rig = make_rig(seed=11, db=tmp_path / db_name, speed=None, deterministic=True)
        out = rig.controller.run(procedure, params, checked=False)  # a design too small to identify
        assert out.state == State.FINISHED, out.faults
        session = rig.store.load_session(out.session_uid)
        assert session.points, "the session measured nothing"
        results = [stable(r) for r in rig.store.results(out.session_uid)]
        values = [(p.point_id, p.start_s, p.pulses, p.Tm_s, p.t1_s, p.t2_s, p.Np) for p in session.points]
        return content_hash(session), values, results, out.faults

    quiet = once("quiet.sqlite")
    with busy_loops(2):
        loaded = once("loaded.sqlite")
    assert loaded[1] == quiet[1]  # every point's stamps and counts, exactly
    assert loaded[0] == quiet[0]  # points, measurements and every raw array: the same bytes
    assert loaded[2] == quiet[2]  # the results of the analysis, every value
    assert loaded[3] == quiet[3]
