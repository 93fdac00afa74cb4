"""Where the gap lies: standardised residuals, their maps, and tests for structure in them.

Standardised residual of point i under a fitted model (whitened by the honest
noise, station.gap.noise): z_i = e_i / (sigma_i sqrt(1 - h_ii)), h_ii the
leverage of the joint fit. Maps: position x frequency, static vs vibration,
run order (time blocks), and the period identity of the timing capture.

Structure tests ("detectors"): a generic block of columns D is added to the
fitted model and tested by F = (dRSS / r) / ((RSS - dRSS) / (dof - r)) on its
channel's rows, r the rank of D after projecting off the model's columns.
Rate blocks: one offset per position (what a free static level would absorb:
index and mount angle errors, a bias step between positions); static position
harmonics {cos k theta, sin k theta}, k = 1..4 (static points); one offset per
frequency (vibration points); position harmonics a^2 {cos k theta, sin k theta}
(vibration points); a cubic trend in session time and its quadratic part alone (every point); one offset per
run-order block; one point off by itself (the largest studentised deleted
residual, Bonferroni over the points: seed 000's reliability test, eq. 28, made
exact); a bias step at the best of the times between points (Bonferroni over them). Timing
blocks (the period identities t1 + Np T - Tm - t2): a slope in
Np T (a frequency error), one frequency error per frequency, one identity off by
itself. Goodness of fit of each channel whose noise is known (stated by the
session; the grating's from thousands of samples): chi-square of its whitened
residual. They find structure that no library effect has to explain, and what
is left after the chosen effects.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.polynomial import legendre
from scipy import stats
from scipy.optimize import minimize_scalar

from station.gap import candidates as cl
from station.gap.design import PointDesign
from station.gap.fit import Channels, ModelFit
from station.gap.forward import CALIBRATED
from station.gap.heldout import BLOCKS
from station.twin.config import TwinConfig


@dataclass(frozen=True)
class Detector:
    name: str
    F: float
    dof: tuple[int, int]
    p_value: float
    what: str
    # Orthonormal whitened columns of the block off the model (rate-channel blocks only).
    basis: np.ndarray | None = field(default=None, repr=False, compare=False)
    at: str = ""  # the point, for a test of one point
    channel: str = "rate"  # rate | timing | grating | pulse

    @property
    def label(self) -> str:
        return f"{self.name} at {self.at}" if self.at else self.name

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "F": _r(self.F),
            "dof": list(self.dof),
            "p_value": _r(self.p_value),
            "tests": self.what,
            "at": self.at or None,
            "channel": self.channel,
        }


def _r(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _blocks(ch: Channels) -> dict[str, tuple[np.ndarray, str]]:
    """Generic structure blocks (physical columns; whitened by the caller)."""
    d = ch.design
    n, n_other = d.n_points, ch.n_other
    vib = d.vib.astype(float)
    out: dict[str, tuple[np.ndarray, str]] = {}
    if d.positions_deg.size >= 2:
        out["position_offsets"] = (
            np.eye(d.positions_deg.size)[d.pos_index],
            "one offset per position (what a free static level would absorb)",
        )
    if (~d.vib).sum() >= 3:
        stat = (~d.vib).astype(float)
        cols = []
        for k in range(1, 5):
            cols += [stat * np.cos(k * d.theta_rad), stat * np.sin(k * d.theta_rad)]
        out["static_position_harmonics"] = (np.column_stack(cols), "static points: cos k theta, sin k theta, k = 1..4")
    freqs = np.unique(d.freq_hz[d.vib])
    if freqs.size:
        out["frequency_offsets"] = (
            np.column_stack([vib * (d.freq_hz == f) for f in freqs]),
            "one offset per vibration frequency",
        )
    a2 = np.zeros(n)
    a2[d.vib] = (d.freq_hz[d.vib] / max(float(d.freq_hz.max()), 1e-9)) ** 4
    cols = []
    for k in range(1, 5):
        cols += [a2 * np.cos(k * d.theta_rad), a2 * np.sin(k * d.theta_rad)]
    out["position_harmonics"] = (np.column_stack(cols), "a^2 cos k theta, a^2 sin k theta, k = 1..4")
    t = d.start_s + 0.5 * d.Tm_s
    span = float(t.max() - t.min())
    if span > 0:
        x = 2.0 * (t - t.min()) / span - 1.0
        out["time_trend"] = (
            np.column_stack([legendre.legval(x, np.eye(4)[k]) for k in (1, 2, 3)]),
            "cubic trend in session time",
        )
        # One dof for the commonest smooth drift left after a linear one (a quadratic, a run-in):
        # more power than the 3-dof cubic block for it.
        out["time_curvature"] = (legendre.legval(x, np.eye(3)[2])[:, None], "quadratic curvature in session time")
    vidx = np.flatnonzero(d.vib)
    if vidx.size >= 2 * BLOCKS:
        order = vidx[np.argsort(d.sequence[vidx], kind="stable")]
        B = np.zeros((n, BLOCKS))
        for j, blk in enumerate(np.array_split(order, BLOCKS)):
            B[blk, j] = 1.0
        out["run_order_blocks"] = (B, f"one offset per run-order block ({BLOCKS} blocks of vibration points)")
    return {k: (np.vstack([v, np.zeros((n_other, v.shape[1]))]), w) for k, (v, w) in out.items()}


def _timing_blocks(ch: Channels) -> dict[str, tuple[np.ndarray, str]]:
    """Generic structure of the period identities (whitened rows of the timing channel)."""
    d = ch.design
    v = d.vib
    span = d.Np[v] / d.freq_hz[v]  # Np T_cmd: tau = -span eps for a frequency error eps
    out = {"period_identity_slope": (span[:, None], "slope of t2 - t1 + Tm - Np T against Np T (a frequency error)")}
    freqs = np.unique(d.freq_hz[v])
    if freqs.size >= 2:
        out["period_identity_per_frequency"] = (
            np.column_stack([span * (d.freq_hz[v] == f) for f in freqs]),
            "one frequency error per frequency (an error that varies with f)",
        )
    pad = ch.n_rate, ch.n_grating
    return {
        k: (np.vstack([np.zeros((pad[0], D.shape[1])), ch.white_tau(D), np.zeros((pad[1], D.shape[1]))]), w)
        for k, (D, w) in out.items()
    }


def _free_on(fit: ModelFit, rows: slice) -> int:
    """Free effect parameters whose columns move these rows."""
    n_lin = fit.J.shape[1] - len(fit.free)
    return int(np.sum(np.linalg.norm(fit.J[rows, n_lin:], axis=0) > 0))


def _test_block(name, D, what, Q, r, rows: slice, rss: float, dof: int, channel: str) -> Detector | None:
    Dp = D - Q @ (Q.T @ D)
    U, s, _ = np.linalg.svd(Dp, full_matrices=False)
    if not s.size or s.max() == 0:
        return None
    U = U[:, s > 1e-8 * s.max()]
    k = U.shape[1]
    dof2 = dof - k
    if k == 0 or dof2 <= 0:
        return None
    drss = float(np.sum((U.T @ r) ** 2))
    F = (drss / k) / max((rss - drss) / dof2, 1e-300)
    return Detector(name, F, (k, dof2), float(stats.f.sf(F, k, dof2)), what, U, channel=channel)


def goodness_of_fit(name: str, chi2: float, dof: int, what: str, channel: str) -> Detector | None:
    """Goodness of fit of a channel with known noise: chi-square of its whitened residual."""
    if dof <= 0:
        return None
    return Detector(name, chi2 / dof, (dof, 0), float(stats.chi2.sf(chi2, dof)), what, channel=channel)


def detectors(ch: Channels, fit: ModelFit) -> list[Detector]:
    """F-tests of generic structure left in the residuals of `fit`, and each known-noise channel's fit."""
    d = ch.design
    n, nt = d.n_points, ch.n_tau
    J = fit.J[:, np.linalg.norm(fit.J, axis=0) > 0]
    Q, _ = np.linalg.qr(J / np.linalg.norm(J, axis=0))
    r = fit.r_white
    rate, tau, grating = slice(0, n), slice(n, n + nt), slice(n + nt, n + ch.n_other)
    rss_rate = float(r[rate] @ r[rate])
    out: list[Detector | None] = []
    wr = np.concatenate([np.sqrt(ch.weights) / ch.sigma0_radps, np.zeros(ch.n_other)])
    for name, (D, what) in _blocks(ch).items():
        out.append(_test_block(name, D * wr[:, None], what, Q, r, rate, rss_rate, fit.dof_rate, "rate"))
    if fit.dof_rate >= 2:
        out.append(_single_point(d, Q, r, rss_rate, fit.dof_rate))
        out.append(_time_step(d, Q, r, wr, rss_rate, fit.dof_rate))
    if ch.rate_sigma_known:
        what = "chi-square of the rate residuals against the stated instrument repeatability"
        out.append(goodness_of_fit("rate_goodness_of_fit", rss_rate, fit.dof_rate, what, "rate"))
    dof_tau = nt - _free_on(fit, tau)
    if nt >= 3:
        rss_tau = float(r[tau] @ r[tau])
        for name, (D, what) in _timing_blocks(ch).items():
            out.append(_test_block(name, D, what, Q, r, tau, rss_tau, dof_tau, "timing"))
        out.append(_single_identity(d, Q, r, tau, rss_tau, dof_tau))
        if ch.tau_sigma_known:
            what = "chi-square of the period identities against the stated timing noise"
            out.append(goodness_of_fit("timing_goodness_of_fit", rss_tau, dof_tau, what, "timing"))
    if ch.n_grating:
        chi2 = float(r[grating] @ r[grating])
        what = "chi-square of the grating rows (harmonics and own frequency of each raw record) against the model"
        out.append(
            goodness_of_fit("grating_goodness_of_fit", chi2, ch.n_grating - _free_on(fit, grating), what, "grating")
        )
    if ch.pulses is not None:
        out.append(pulse_goodness_of_fit(ch, fit))
    return [x for x in out if x is not None]


# Parameters that the window means do not see but the pulse edges do are profiled in the pulse test, as the
# chosen effects' modules declare them (station.twin.effects.base.Effect: pulse_phase, pulse_folded): a phase on a grid
# over one turn, then bounded; a folded parameter as a column within its bound.
PHASE_GRID = 24


def _pulse_only(chosen: list[str]) -> tuple[list[tuple[str, str]], list[cl.FreeParam]]:
    """The phases the chosen effects declare, and the parameters they fold whose effect is not chosen too."""
    effects = [cl.LIBRARY[n].effect for n in chosen]
    phases = [(e.name, e.pulse_phase) for e in effects if e.pulse_phase]
    folded: dict[str, cl.FreeParam] = {}
    for e in effects:
        if e.pulse_folded and e.pulse_folded[0] not in chosen:
            name, param = e.pulse_folded
            fp = next(fp for fp in cl.LIBRARY[name].free if fp.param == param)
            folded[fp.key] = fp
    return phases, list(folded.values())


def _profile_phase(
    cfg: TwinConfig, name: str, param: str, chi2_at: Callable[[TwinConfig], float]
) -> tuple[TwinConfig, float]:
    """The twin with effect `name`'s phase `param` at the minimum of chi2_at over a turn, and that minimum."""
    current = dict(cfg.effects[name])

    def at_phase(phi: float) -> float:
        return chi2_at(cfg.with_effect(name, **{**current, param: float(phi)}))

    grid = 2 * math.pi * np.arange(PHASE_GRID) / PHASE_GRID
    best = grid[int(np.argmin([at_phase(x) for x in grid]))]
    step = 2 * math.pi / PHASE_GRID
    res = minimize_scalar(at_phase, bounds=(best - step, best + step), method="bounded", options={"xatol": 1e-4})
    return cfg.with_effect(name, **{**current, param: float(res.x)}), float(res.fun)


def pulse_goodness_of_fit(ch: Channels, fit: ModelFit) -> Detector | None:
    """Chi-square of the pulse edges' rate harmonics against the fitted twin (station.gap.rawstreams.PulseRecord).

    The prediction's uncertainty is carried in: G Cov G^T with G = d(harmonics)/d(K, effect parameters) by
    forward differences (linear in K; the effects' own fd steps), Cov the fit's covariance of K and a prior as
    wide as its plausible bound for each effect parameter (linearised at the fitted values); the parameters only
    the pulses see (above) are profiled, one dof each. The rate noise may be white (physics.md: the window mean
    of a rate that averages down as 1/sqrt(Tm)); integrated, it is a random walk of the angle at the edges.
    Its density D is what each record's scatter beyond its stamps' implies (PulseFit), at most var(wbar) Tm
    (all of the window's rate variance, stated or estimated, white): its covariance enters as well
    (PulseRecord.covariance), so the test holds whichever form the noise has."""
    pulses = ch.pulses
    if pulses is None:
        return None
    d = ch.design
    walk_D = np.minimum(pulses.walk_density, ch.sigma0_radps**2 / ch.weights[pulses.index] * d.Tm_s[pulses.index])
    chosen = [n for n in cl.LIBRARY if n in {fp.effect for fp in fit.free}]
    phases, folded = _pulse_only(chosen)
    n_nuisance = len(phases) + len(folded)

    # The prior covariance of what the columns below move, the same at every phiL: K as fitted, the effects'
    # parameters free within their plausible bounds (a wide prior, in units of their scale): the pulses are not in
    # the fit, so the test asks whether the chosen effects can reproduce them at all (the rate fit's own values,
    # pulled by what the rates cannot separate, need not); a folded parameter within its bound.
    n_k = len(CALIBRATED)
    sd_K = np.sqrt(np.clip(np.diag(fit.cov)[d.n_levels : d.n_levels + n_k], 0, None))
    steps_K = [max(float(sd), 1e-9 * max(abs(float(k)), 1e-6)) for k, sd in zip(fit.K, sd_K, strict=True)]
    cov = fit.cov[d.n_levels :, d.n_levels :].copy()
    cov[n_k:, :] = 0.0
    cov[:, n_k:] = 0.0
    cov[n_k:, n_k:] = np.diag([min(fp.bound, 1e3 * fp.scale) ** 2 / fp.scale**2 for fp in fit.free])
    for fp in folded:
        m = cov.shape[0]
        cov = np.pad(cov, ((0, 1), (0, 1)))
        cov[m, m] = fp.bound**2

    def chi2_at(cfg) -> float:
        p0 = pulses.predict(d, cfg)
        cols = []
        for name, k, h in zip(CALIBRATED, fit.K, steps_K, strict=True):
            cfg_h = replace(cfg, instrument=replace(cfg.instrument, **{name: float(k) + h}))
            cols.append((pulses.predict(d, cfg_h) - p0) / h)
        for fp, v in zip(fit.free, fit.values, strict=True):
            cfg_h = cl.apply(cfg, [fp], [float(v) + fp.fd_step], {})
            cols.append((pulses.predict(d, cfg_h) - p0) / fp.fd_step * fp.scale)
        for fp in folded:
            cfg_h = cl.apply(cfg, [fp], [fp.fd_step], {})
            cols.append((pulses.predict(d, cfg_h) - p0) / fp.fd_step)
        return pulses.chi2(d, cfg, np.column_stack(cols), cov, walk_D)

    cfg = fit.refitted_cfg()
    chi2 = None
    for name, param in phases:
        cfg, chi2 = _profile_phase(cfg, name, param, chi2_at)
    chi2 = chi2_at(cfg) if chi2 is None else chi2
    what = "chi-square of the rate harmonics the pulse edges give (raw records) against the fitted twin"
    if n_nuisance:
        only = ", ".join([f"{n}.{p}" for n, p in phases] + [fp.key for fp in folded])
        what += f" ({n_nuisance} parameter(s) only the pulses see profiled: {only})"
    return goodness_of_fit("pulse_goodness_of_fit", chi2, pulses.n_rows - n_nuisance, what, "pulse")


def _single_identity(d: PointDesign, Q, r, rows: slice, rss: float, dof: int) -> Detector | None:
    """The period identity whose own offset lowers the timing RSS most (Bonferroni over the identities)."""
    if dof < 2:
        return None
    h = np.sum(Q[rows] ** 2, axis=1)
    e = r[rows]
    drss = e**2 / np.clip(1.0 - h, 1e-12, None)
    i = int(np.argmax(drss))
    F = float(drss[i]) / max((rss - float(drss[i])) / (dof - 1), 1e-300)
    p = min(1.0, e.size * float(stats.f.sf(F, 1, dof - 1)))
    pid = d.point_ids[int(np.flatnonzero(d.vib)[i])]
    what = f"one period identity off by itself (the largest of {e.size}, Bonferroni)"
    return Detector("single_identity", F, (1, dof - 1), p, what, at=pid, channel="timing")


MIN_STEP_POINTS = 3  # points on each side of a step in session time


def _time_step(d: PointDesign, Q, r, wr, rss_rate: float, dof: int) -> Detector | None:
    """A bias step at some time of the session: the step whose offset lowers the RSS most, Bonferroni over
    the candidate times (between consecutive points in session time, MIN_STEP_POINTS on each side).
    A smooth trend test (time_trend) spreads a step over its cubic; this scan gives it one column."""
    n = d.n_points
    order = np.argsort(d.start_s, kind="stable")
    ks = np.arange(MIN_STEP_POINTS, n - MIN_STEP_POINTS + 1)
    if not ks.size:
        return None

    def tail(x: np.ndarray) -> np.ndarray:  # tail(x)[k] = sum of x[order[m]] for m >= k (a step's column sums)
        return np.cumsum(x[order][::-1], axis=0)[::-1][ks]

    w = wr[:n]
    QD = tail(Q[:n] * w[:, None])  # Q^T D_k, one row per step time
    norm2 = tail(w * w) - np.sum(QD**2, axis=1)  # |D_k off the model|^2
    ok = norm2 > 1e-12 * np.max(norm2)
    num = tail(r[:n] * w) - QD @ (Q.T @ r)
    drss = np.where(ok, num**2 / np.where(ok, norm2, 1.0), 0.0)
    j = int(np.argmax(drss))
    F = float(drss[j]) / max((rss_rate - float(drss[j])) / (dof - 1), 1e-300)
    p = min(1.0, int(ok.sum()) * float(stats.f.sf(F, 1, dof - 1)))
    column = np.zeros(r.size)
    column[order[ks[j] :]] = w[order[ks[j] :]]
    column -= Q @ (Q.T @ column)
    k = order[ks[j]]
    what = f"a bias step in session time (the best of {int(ok.sum())} step times, Bonferroni)"
    basis = (column / np.linalg.norm(column))[:, None]
    return Detector("time_step", F, (1, dof - 1), p, what, basis, f"{d.start_s[k]:.0f} s")


def _single_point(d: PointDesign, Q: np.ndarray, r: np.ndarray, rss_rate: float, dof: int) -> Detector:
    """The point whose own offset lowers the RSS most: drss_i = r_i^2 / (1 - h_i) (r is off the model)."""
    n = d.n_points
    h = np.sum(Q[:n] ** 2, axis=1)
    drss = r[:n] ** 2 / np.clip(1.0 - h, 1e-12, None)
    i = int(np.argmax(drss))
    F = float(drss[i]) / max((rss_rate - float(drss[i])) / (dof - 1), 1e-300)
    p = min(1.0, n * float(stats.f.sf(F, 1, dof - 1)))
    column = -Q @ Q[i]
    column[i] += 1.0
    basis = (column / np.linalg.norm(column))[:, None]
    what = f"one point off by itself (the largest of {n} studentised residuals, Bonferroni)"
    return Detector("single_point", F, (1, dof - 1), p, what, basis, d.point_ids[i])


def significant(dets: list[Detector], alpha: float) -> list[Detector]:
    """The structure tests significant at level alpha, Bonferroni over the family."""
    return [d for d in dets if d.p_value < alpha / max(len(dets), 1)]


def standardised(fit: ModelFit, ch: Channels, rate_sigma_ratio: float) -> np.ndarray:
    """z_i = e_i / (sigma_i sqrt(1 - h_ii)) for every rate row (honest sigma)."""
    n = ch.n_rate
    J = fit.J[:, np.linalg.norm(fit.J, axis=0) > 0]
    Q, _ = np.linalg.qr(J / np.linalg.norm(J, axis=0))
    h = np.sum(Q[:n] ** 2, axis=1)
    return fit.r_white[:n] / rate_sigma_ratio / np.sqrt(np.clip(1.0 - h, 1e-6, None))


def _group(z: np.ndarray, mask: np.ndarray) -> dict:
    zz = z[mask]
    if zz.size == 0:
        return {"n": 0}
    chi2 = float(np.sum(zz**2))
    return {
        "n": int(zz.size),
        "mean_z": float(zz.mean()),
        "rms_z": float(np.sqrt(np.mean(zz**2))),
        "chi2": chi2,
        "p_value": float(stats.chi2.sf(chi2, zz.size)),
    }


def maps(design: PointDesign, z: np.ndarray, tau_z: np.ndarray) -> dict:
    """Group summaries of standardised residuals: position, frequency, kind, run order, timing."""
    d = design
    out: dict = {"by_position": [], "by_frequency": [], "by_kind": {}, "by_time_block": [], "grid": []}
    for j, p in enumerate(d.positions_deg):
        out["by_position"].append({"position_deg": float(p), **_group(z, d.pos_index == j)})
    for f in np.unique(d.freq_hz):
        label = "static" if f == 0 else float(f)
        out["by_frequency"].append({"freq_hz": label, **_group(z, d.freq_hz == f)})
    out["by_kind"] = {"static": _group(z, ~d.vib), "vibration": _group(z, d.vib)}
    order = np.argsort(d.sequence, kind="stable")
    for j, blk in enumerate(np.array_split(order, min(BLOCKS, max(1, d.n_points // 4)))):
        m = np.zeros(d.n_points, dtype=bool)
        m[blk] = True
        out["by_time_block"].append(
            {
                "block": j,
                "start_s": float(d.start_s[blk].min()),
                "end_s": float((d.start_s + d.Tm_s)[blk].max()),
                **_group(z, m),
            }
        )
    for i in range(d.n_points):
        out["grid"].append(
            {
                "point_id": d.point_ids[i],
                "position_deg": float(d.position_deg[i]),
                "freq_hz": float(d.freq_hz[i]),
                "sequence": int(d.sequence[i]),
                "z": float(z[i]),
            }
        )
    if tau_z.size:
        out["timing"] = {
            "n": int(tau_z.size),
            "rms_z": float(np.sqrt(np.mean(tau_z**2))),
            "chi2": float(np.sum(tau_z**2)),
            "p_value": float(stats.chi2.sf(np.sum(tau_z**2), tau_z.size)),
        }
    return out


def _largest(groups: list[dict], n: int) -> list[dict]:
    """The n groups of a map with points, largest rms z first."""
    return sorted([g for g in groups if g.get("n")], key=lambda g: -g["rms_z"])[:n]


def _kinds_text(by_kind: dict) -> list[str]:
    """The rms z of the static and of the vibration points, where the session has both."""
    if not (by_kind.get("static", {}).get("n") and by_kind.get("vibration", {}).get("n")):
        return []
    static, vibration = by_kind["static"]["rms_z"], by_kind["vibration"]["rms_z"]
    return [f"static points rms z {static:.2f}, vibration points rms z {vibration:.2f}"]


def _largest_text(m: dict) -> list[str]:
    """Where the residuals are largest: the worst frequency, the two worst positions, the worst run-order block."""
    out = [
        f"largest at {g['freq_hz']}{' Hz' if g['freq_hz'] != 'static' else ''} "
        f"(rms z {g['rms_z']:.2f}, mean z {g['mean_z']:+.2f})"
        for g in _largest(m["by_frequency"], 1)
    ]
    pos = _largest(m["by_position"], 2)
    if pos:
        out.append("positions " + ", ".join(f"{g['position_deg']:g} deg (rms z {g['rms_z']:.2f})" for g in pos))
    out += [
        f"run-order block {g['block']} ({g['start_s']:.0f}-{g['end_s']:.0f} s, rms z {g['rms_z']:.2f})"
        for g in _largest(m["by_time_block"], 1)
    ]
    return out


def _structure_text(dets: list[Detector], alpha: float) -> str:
    """The structure tests significant at alpha (Bonferroni over the tests), or that none is."""
    sig = significant(dets, alpha)
    if sig:
        return "structure: " + "; ".join(f"{dt.label} F = {dt.F:.1f} (p = {dt.p_value:.1e})" for dt in sig)
    return f"no structure test significant at the {alpha:.2g} level (Bonferroni over {len(dets)} tests)"


def where_text(m: dict, dets: list[Detector], alpha: float) -> str:
    """Where the gap lies, in words and numbers."""
    parts = _kinds_text(m["by_kind"]) + _largest_text(m)
    if "timing" in m:
        parts.append(f"period identities rms z {m['timing']['rms_z']:.2f}")
    return "; ".join([*parts, _structure_text(dets, alpha)]) + "."
