"""Issue 30, deliverable 7 (the panel's part): a bounded fuzz campaign over the panel's uploads and requests.

`station panel` runs in its own process as an operator starts it (bench/fuzz_panel.py's PanelProcess: its log
is what it writes on stderr); hypothesis draws mangled session archives, broken multipart framing, chunked and
Content-Length bodies, clients that give up half-way, and every route with made-up parameters, headers and
bodies, as anyone, a viewer or an operator (bench.fuzz_panel.cases), from a fixed seed. For every request: no
5xx, an answer to every request sent whole, the store unchanged by a refusal, no upload work directory left;
at the end, no traceback in the panel's log. Bodies over the bound (MAX_BODY_BYTES) are refused with 413 however
they come. The long campaign is `bench/fuzz_panel.py` (BENCHMARKS.md).

Bounds: EXAMPLES requests and two bodies over the bound in about 15 s on the 2-core machine (the test's timeout:
120 s); no tolerance on any count (all exact zeros).
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, given, seed, settings

from bench.fuzz_panel import PanelProcess, Tally, cases, check, lawful_archive, oversized_case

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore:Duplicate name")]
EXAMPLES = 120
SEED = 30


@pytest.fixture(scope="module")
def panel(tmp_path_factory) -> Iterator[PanelProcess]:
    with PanelProcess(tmp_path_factory.mktemp("fuzz") / "run") as p:
        yield p
        time.sleep(0.3)  # the last request's log lines
        log = p.log.read_text(errors="replace")
        assert p.tracebacks() == 0, log[-4000:]


LAWFUL = lawful_archive()


@seed(SEED)
@settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=False,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                 HealthCheck.data_too_large])  # fmt: skip
@given(case=cases(LAWFUL))
def test_no_request_gets_a_5xx_changes_the_store_on_refusal_or_leaves_files(panel, case) -> None:
    tally = Tally()
    digest = panel.store_digest()
    check(panel, case, tally, digest)
    assert not tally.server_errors, tally.server_errors
    assert not tally.unanswered, tally.unanswered
    assert tally.store_changed == 0, case
    assert tally.leftovers == 0, panel.leftovers()
    assert panel.tracebacks() == 0, (case, panel.log.read_text(errors="replace")[-4000:])


@pytest.mark.parametrize("chunked", [False, True], ids=["content-length", "chunked"])
def test_a_body_over_the_bound_is_refused_with_413_and_stores_nothing(panel, chunked) -> None:
    tally = Tally()
    digest = panel.store_digest()
    outcome = check(panel, oversized_case(chunked, "victor", 1), tally, digest)
    assert outcome.status == 413 and not tally.oversized_not_413
    assert tally.store_changed == 0 and tally.leftovers == 0
