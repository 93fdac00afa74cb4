"""The held-out gap is computed on data the fit did not see, and standardised by the predictive variance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from station.gap.design import PointDesign
from station.gap.heldout import Folds, HeldOut, heldout, shrink


@pytest.fixture(scope="module")
def design(seed000_session):
    return PointDesign.from_session(seed000_session("null", None, 0.0, 1001)[0])


def test_folds_hold_out_every_point_once_per_scheme(design):
    """Static points too: the twin predicts every static rate (one bias k0, no free level per position)."""
    folds = Folds.of(design)
    assert set(folds.schemes) == {"leave_position_out", "leave_frequency_out", "leave_time_block_out"}
    for scheme, sets in folds.schemes.items():
        held = np.concatenate(sets)
        assert sorted(held) == list(range(design.n_points)), scheme  # every point once
    for held in folds.schemes["leave_position_out"]:
        assert np.unique(design.position_deg[held]).size == 1
    for held in folds.schemes["leave_frequency_out"]:
        assert np.unique(design.freq_hz[held]).size == 1
    for held in folds.schemes["leave_time_block_out"]:
        seq = np.sort(design.sequence[held])
        others = np.setdiff1d(design.sequence, seq)
        assert not np.any((others > seq[0]) & (others < seq[-1]))  # contiguous in run order


def _brute_force(J, y, design, folds) -> float:
    """Refit on the training rows with lstsq, predict the held-out rows, z^2 = e^2 / (1 + x Cov x)."""
    n = design.n_points
    vib = np.flatnonzero(design.vib)
    tau_row = {int(i): n + k for k, i in enumerate(vib)}
    means = []
    for sets in folds.schemes.values():
        z2 = []
        for held in sets:
            rows = list(held) + [tau_row[int(i)] for i in held if int(i) in tau_row]
            train = np.setdiff1d(np.arange(y.size), rows)
            beta, *_ = np.linalg.lstsq(J[train], y[train], rcond=None)
            cov = np.linalg.inv(J[train].T @ J[train])
            for i in rows:
                z2.append((y[i] - J[i] @ beta) ** 2 / (1.0 + J[i] @ cov @ J[i]))
        means.append(np.mean(z2) - 1.0)
    return float(np.mean(means))


def _linear_problem(design, structure: float, seed: int = 0):
    """Whitened rows (rate, then period identities) of a linear model with unit noise, plus structure."""
    rng = np.random.default_rng(seed)
    n_rows = design.n_points + int(design.vib.sum())
    J = rng.normal(size=(n_rows, 6))
    y = J @ rng.normal(size=6) + rng.normal(size=n_rows)
    y[: design.n_points] += structure * np.cos(np.radians(design.position_deg) * 3)  # not in J's span
    beta, *_ = np.linalg.lstsq(J, y, rcond=None)
    return J, y, y - J @ beta


def test_the_held_out_gap_is_that_of_an_explicit_refit_without_the_fold(design):
    folds = Folds.of(design)
    J, y, r = _linear_problem(design, structure=3.0)
    got = heldout(J, r, design, folds, 1.0, 1e-6, 1e-7)
    assert pytest.approx(_brute_force(J, y, design, folds), rel=1e-9) == got.G


def test_a_right_model_has_no_held_out_gap_and_structure_has_one(design):
    folds = Folds.of(design)
    right = [heldout(*_linear_problem(design, 0.0, seed)[::2], design, folds, 1.0, 1e-6, 1e-7) for seed in range(20)]
    G = np.array([h.G for h in right])
    # mean of 20 gaps, each with se sqrt(2 / rows): within 4 se / sqrt(20) of 0
    assert abs(G.mean()) < 4 * right[0].se / math.sqrt(20)
    gap = heldout(*_linear_problem(design, 3.0)[::2], design, folds, 1.0, 1e-6, 1e-7)
    assert 4 * gap.se < gap.G
    assert gap.rate_excess_rms_radps > np.median([h.rate_excess_rms_radps for h in right])


def test_shrink_is_the_fraction_of_the_held_out_gap_removed():
    def h(G: float) -> HeldOut:
        return HeldOut(G, {}, {}, 0.1, 0.0, 0.0, 60)

    assert shrink(h(2.0), h(0.5)) == pytest.approx(0.75)
    assert shrink(h(2.0), h(-0.1)) == pytest.approx(1.05)
    assert shrink(h(0.15), h(0.0)) is None  # no gap beyond 2 se to shrink
