"""The two simulation paths on a common design and common seeds: the engine on the deterministic station and the
session_sim shortcut (issue 27 step 3, deliverable 4).

They cannot agree point by point: the engine's crank phase at a window's opening follows from the station's whole
timeline (index moves, ramps, settling, the drivers' exchanges; on the deterministic station nearly the same phase
for a given design whatever the seed), the shortcut draws it uniformly, and the two draw their rate-noise offsets
from different generators; the engine's counter stamps are tick-quantised without the shortcut's timing jitter.
Measured on seed 000's full design (seeds 0-3): design fields identical; static Tm 1.6-4.6 ms apart (rms, 3-9e-6
relative: rate noise), vibration Tm 0.15-0.18 s and Np up to 4 periods apart (phase). So this test checks what the
shortcut is kept for, identification and uncertainty studies: that its sessions are statistically the engine's.

Design: integral_precession at its 10 positions, 8 and 10 Hz, 30 s windows (30 points, dof 16 a session), seeds 1-6:
about 3 s of CPU per engine session. Tolerances, each from the noise model the twin states (rate noise 1e-6 rad/s
over 560 s, white: sd of a window's mean rate 1e-6 sqrt(560 / Tm)):
- every point's design fields (id, position, frequency, kind, preset pulses) identical: exact;
- the period identity t1 + Np T - Tm - t2 = 0: engine within 2 ticks (100 ns: two quantised stamps), shortcut
  within 2 ticks + 5 sqrt(3) x 1e-7 s (three stamps each with the twin's 1e-7 s jitter);
- each point's measured rate minus the twin's truth, over that sd (z): per path and kind (static, vibration),
  pooled over seeds, |mean| <= 4 / sqrt(n) and the variance within the chi-square(n - 1) bounds at two-sided 1e-4;
  engine against shortcut: variance ratio within F's bounds at two-sided 1e-3, means within 4 sigma of each other;
- identified kz, kzz, ky, k3: per seed and path |k - true| <= 4.5 sigma_k (Student t, 16 dof: p 4e-4), the two
  paths' estimates within 4.5 sqrt(sigma_e^2 + sigma_s^2), and per path the mean over seeds of (k - true) / sigma_k
  within 4 / sqrt(6);
- the residual sigma: per path, sum(dof sigma^2 / sigma_expected^2) within the chi-square(sum dof) bounds at
  two-sided 1e-4 (sigma_expected = 1e-6 sqrt(560 / mean Tm): the fit weights w = Tm / mean Tm), and the paths'
  pooled variances in a ratio within F's bounds at two-sided 1e-3.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from engine_sessions import engine_session, shortcut_session
from scipy import stats

from procedures.integral_precession.identify import design, identify
from station.session import Session
from station.twin.config import default_twin
from station.twin.effects import terms
from station.twin.precession import periodic_rate

PARAMS = {"positions_deg": [0, 36, 72, 108, 144, 180, 216, 252, 288, 324], "freqs_hz": [8, 10], "window_s": 30}
SEEDS = range(1, 7)
TICK_S = 5e-8


def _z_at_truth(s: Session) -> tuple[np.ndarray, np.ndarray]:
    """(z of every point's rate against the twin's truth, mask of the vibration points)."""
    twin = default_twin()
    k = twin.instrument
    rates, _, L, _, vib = design(s)
    c0 = np.array([periodic_rate(math.radians(p.position_deg), 0.0, twin).c0_radps for p in s.points])
    tm = np.array([p.Tm_s for p in s.points])
    sd = twin.noise.rate_noise_radps * np.sqrt(twin.noise.rate_noise_ref_s / tm)
    return (rates - c0 - L @ np.array([k.kz, k.kzz, k.ky, k.k3])) / sd, vib


def _period_identity_s(s: Session) -> np.ndarray:
    """t1 + Np T - Tm - t2 of every vibration point (T = 1 / f: the default twin has no frequency error)."""
    assert terms.frequency_offset(default_twin().effects) == 0.0
    return np.array([p.t1_s + p.Np / p.freq_hz - p.Tm_s - p.t2_s for p in s.points if p.Np is not None])


def _chi2_ok(sum_sq: float, dof: int, level: float) -> bool:
    return bool(stats.chi2.ppf(level / 2, dof) <= sum_sq <= stats.chi2.ppf(1 - level / 2, dof))


def _f_ok(ratio: float, d1: int, d2: int, level: float) -> bool:
    return bool(stats.f.ppf(level / 2, d1, d2) <= ratio <= stats.f.ppf(1 - level / 2, d1, d2))


@pytest.mark.slow
def test_the_shortcut_is_statistically_the_engine_on_a_common_design() -> None:
    twin = default_twin()
    truth = {n: getattr(twin.instrument, n) for n in ("kz", "kzz", "ky", "k3")}
    z = {"engine": [], "shortcut": []}
    coef_z = {"engine": [], "shortcut": []}
    res = {"engine": [0.0, 0], "shortcut": [0.0, 0]}  # sum dof sigma^2 / sigma_expected^2, sum dof
    for seed in SEEDS:
        sessions = {"engine": engine_session(PARAMS, seed), "shortcut": shortcut_session(PARAMS, seed)}
        e, c = sessions["engine"].points, sessions["shortcut"].points
        assert [(p.point_id, p.position_deg, p.freq_hz, p.kind, p.pulses) for p in e] == [
            (p.point_id, p.position_deg, p.freq_hz, p.kind, p.pulses) for p in c
        ], f"seed {seed}: the two paths measured different designs"
        ident_e, ident_c = _period_identity_s(sessions["engine"]), _period_identity_s(sessions["shortcut"])
        assert np.abs(ident_e).max() <= 2 * TICK_S, f"seed {seed}: engine period identity off by {ident_e}"
        bound_c = 2 * TICK_S + 5 * math.sqrt(3) * twin.noise.timing_jitter_s
        assert np.abs(ident_c).max() <= bound_c, f"seed {seed}: shortcut period identity off by {ident_c}"
        fits = {}
        for path, s in sessions.items():
            z[path].append(_z_at_truth(s))
            fit = identify(s)
            fits[path] = fit
            coef_z[path].append([(fit.coefficient(n)[0] - truth[n]) / fit.coefficient(n)[1] for n in truth])
            sigma_expected = twin.noise.rate_noise_radps * math.sqrt(
                twin.noise.rate_noise_ref_s / np.mean([p.Tm_s for p in s.points])
            )
            res[path][0] += fit.dof * (fit.sigma_residual / sigma_expected) ** 2
            res[path][1] += fit.dof
        for n in truth:
            (ve, se), (vc, sc) = fits["engine"].coefficient(n), fits["shortcut"].coefficient(n)
            assert abs(ve - vc) <= 4.5 * math.hypot(se, sc), (
                f"seed {seed}: {n} engine {ve} +- {se}, shortcut {vc} +- {sc}"
            )

    for path in ("engine", "shortcut"):
        cz = np.array(coef_z[path])
        assert np.abs(cz).max() <= 4.5, f"{path}: (k - true) / sigma_k per seed {cz.round(2).tolist()}"
        assert np.all(np.abs(cz.mean(axis=0)) <= 4 / math.sqrt(len(SEEDS))), f"{path}: mean z {cz.mean(axis=0)}"
        sum_sq, dof = res[path]
        assert _chi2_ok(sum_sq, dof, 1e-4), f"{path}: residual sigma^2 / expected pooled {sum_sq / dof:.3f} ({dof} dof)"

    zs = {path: (np.concatenate([a for a, _ in z[path]]), np.concatenate([v for _, v in z[path]])) for path in z}
    for kind, want_vib in (("static", False), ("vibration", True)):
        part = {path: zz[vv == want_vib] for path, (zz, vv) in zs.items()}
        for path, x in part.items():
            n = x.size
            assert abs(x.mean()) <= 4 / math.sqrt(n), f"{path} {kind}: mean z {x.mean():.3f} over {n} points"
            assert _chi2_ok(float(((x - x.mean()) ** 2).sum()), n - 1, 1e-4), f"{path} {kind}: z sd {x.std(ddof=1):.3f}"
        xe, xc = part["engine"], part["shortcut"]
        ratio = xe.var(ddof=1) / xc.var(ddof=1)
        assert _f_ok(ratio, xe.size - 1, xc.size - 1, 1e-3), f"{kind}: z variance engine / shortcut {ratio:.3f}"
        diff_sd = math.sqrt(xe.var(ddof=1) / xe.size + xc.var(ddof=1) / xc.size)
        assert abs(xe.mean() - xc.mean()) <= 4 * diff_sd, f"{kind}: mean z {xe.mean():.3f} vs {xc.mean():.3f}"

    ratio = (res["engine"][0] / res["engine"][1]) / (res["shortcut"][0] / res["shortcut"][1])
    assert _f_ok(ratio, res["engine"][1], res["shortcut"][1], 1e-3), f"residual variance ratio {ratio:.3f}"
