"""The shared development set ../shared/gap-devset (issue 28): 29 sessions from an implementation of physics.md
that shares no code with the project, diagnosed blind against the default twin and scored by the set's own
README (bench/bench_gap_devset.py's `right`): a library effect at SNR >= 10 `explained` first or `cannot_tell`
naming it with a look-alike, a pair with both named, a null `no_gap`, an out-of-library effect never
`explained`. Below SNR 10 the same rule is asserted where it is met today.

Every case is asserted (BENCHMARKS.md gives each one's cause where the diagnosis and the truth parted).
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("bench_gap_devset", ROOT / "bench" / "bench_gap_devset.py")
assert _spec is not None and _spec.loader is not None
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)

if not (bench.DEVSET / "truth" / "_index.json").is_file():
    pytest.skip(f"no development set at {bench.DEVSET}", allow_module_level=True)


@functools.cache
def _row(case_id: str) -> dict:
    return bench.run_case(case_id)


@pytest.mark.parametrize("case_id", bench.case_ids())
def test_devset_case_is_scored_right(case_id: str) -> None:
    """One case against the set's rule (today every case: SNR >= 10 17 of 17, pairs 2 of 2, nulls 3 of 3,
    out-of-library 0 of 2 explained, below SNR 10 5 of 5)."""
    r = _row(case_id)
    assert bench.right(r), (r["truth"], r["verdict"], r["effects"], r["ambiguous"], r["partial"], r["text"])


@pytest.mark.parametrize("case_id", bench.case_ids())
def test_devset_cannot_tell_names_two_effects_or_more(case_id: str) -> None:
    """Issue 28, deliverable 2, on every case (station.gap.verdict.Verdict refuses it when made; asserted here too):
    a `cannot_tell` names at least two effects, each in its text, and explains none."""
    r = _row(case_id)
    if r["verdict"] == "cannot_tell":
        assert len(set(r["ambiguous"])) >= 2 and not r["effects"], (r["ambiguous"], r["text"])
        assert all(e in r["text"] for e in r["ambiguous"]), r["text"]


def test_a_pair_that_one_many_parameter_effect_absorbs_is_named_with_it():
    """c05bc5fc, 6 positions: 4 index harmonics take the static pattern of a mount tilt and a bias drift alike
    (greedy selection chose them alone); the pair is the model of lower BIC, the harmonics its alternative. The
    pair's parameters within 3 sd of the truth."""
    r = _row("c05bc5fc")
    assert r["verdict"] == "cannot_tell", r["text"]
    assert {"mount_misalignment", "bias_drift", "index_harmonics"} <= set(r["ambiguous"])
    assert "index_harmonics (which reproduces it)" in r["text"]
    for effect, params in r["parameters"].items():
        for name, p in params.items():
            assert abs(p["z"]) < 3.0, (effect, name, p)


def test_one_effect_with_aliased_parameters_is_explained_and_they_are_marked_undetermined():
    """26bfeb2a: index harmonics on 6 equal-angle positions (60 deg apart), where cos 2th = cos 4th and
    sin 2th = -sin 4th at every position and sin 3th = 0: c4 is fitted as c2 + c4, s4 as s4 - s2 (within 3 sd)."""
    r = _row("26bfeb2a")
    assert r["verdict"] == "explained" and r["effects"] == ["index_harmonics"], r["text"]
    assert "not determined by this design" in r["text"] and "c2, s2, c3, s3" in r["text"]
    p = r["parameters"]["index_harmonics"]
    truth = bench.json.loads((bench.DEVSET / "truth" / "26bfeb2a.json").read_text())["effects"]["index_harmonics"]
    assert abs(p["c4"]["value"] - (truth["c2"] + truth["c4"])) < 3.0 * p["c4"]["sd"]
    assert abs(p["s4"]["value"] - (truth["s4"] - truth["s2"])) < 3.0 * p["s4"]["sd"]
