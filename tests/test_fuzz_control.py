"""Fuzzing the control channel's frames (issue 30, deliverable 7): whatever arrives, the server does not crash,
nothing unauthenticated (wrong MAC, identity or stamp, replayed, stale) reaches the controller, and a valid request
sent right after is answered. Fixed seed, a few seconds; bench/fuzz_control.py runs the long campaign."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from control_fuzz import Rig
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    rig = Rig.start()
    yield rig
    rig.close()


@seed(30)
@settings(max_examples=1000, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_no_frame_crashes_the_server_or_acts_unauthenticated(rig, data) -> None:
    assert rig.fuzz_one(data.draw) == []
