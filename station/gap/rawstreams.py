"""What the raw streams say: the grating's harmonics and the pulse-rate spectrum (physics.md raw/).

Per vibration point with raw/<point_id>.npz, with the apparent crank phase
psi_a(t) = w_m (t - t1) (w_m = 2 pi Np / (t2 + Tm - t1), from the record's own
timing capture, so the reduction needs no model):
- grating: least squares of z(t) on 1, sin j psi_a, cos j psi_a (j = 1..3)
  gives (Zs1 + A0, Zc1, Zs2, Zc2, Zs3, Zc3) as the read head sees them; the
  twin predicts the same numbers from table_position_m at psi = psi_a + w delta
  (latency shifts the reference); the differences are the waveform gap. Their
  standard errors combine the fit's residual scatter with the phase error of
  the stamp t1 (sd_stamp): psi_a off by e turns (Zsj, Zcj) by j e, so
  se(Zcj) = j w sd_stamp |Zsj| and se(Zsj) = j w sd_stamp |Zcj|.
- pulses: the precession angle at every pulse edge (the level it crosses,
  from the up/down count, times the pulse angle) fitted by phi0 + c0 t + sum_j (A_j sin j psi_a +
  B_j cos j psi_a) gives the rate's harmonics r_j = j w (A_j, B_j); the twin
  predicts them from periodic_rate (rotated by the latency phase).
At most MAX_SAMPLES samples per stream are used (evenly strided).
Across points, the grating differences are summarised as the waveform
parameters they imply: dZs1 = dz0 + dz1 w, and the mean of each other harmonic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from station.gap.design import PointDesign
from station.session import Session
from station.twin.config import TwinConfig
from station.twin.effects import terms
from station.twin.inputs import table_position_m
from station.twin.precession import N_PHASES, periodic_rate

MAX_SAMPLES = 200_000
# A harmonic of a quantised record without dither is not trusted below its quantum (the read head's
# resolution, 1 nm in station.twin.raw): the quantisation error is then periodic with the motion and leaves biases
# of a few 0.1 nm that no sample scatter shows. With sample noise above the quantum the error is dithered
# and averages down like the noise. A smallest step between distinct values below MIN_QUANTUM_M: unquantised.
MIN_QUANTUM_M = 1e-11


def grating_floor_m(z_m: np.ndarray, residual_sd_m: float) -> float:
    """The record's quantum (its smallest step between distinct values) when the noise does not dither it."""
    u = np.unique(z_m)
    q = float(np.min(np.diff(u))) if u.size > 1 else 0.0
    return q if q >= MIN_QUANTUM_M and residual_sd_m < q else 0.0


HARMONICS = (1, 2, 3)
_GRATING_NAMES = ("Zs1+A0", "Zc1", "Zs2", "Zc2", "Zs3", "Zc3")


def _design(psi: np.ndarray, with_line: np.ndarray | None = None) -> np.ndarray:
    cols = [np.ones_like(psi)]
    if with_line is not None:
        cols.append(with_line)
    for j in HARMONICS:
        cols += [np.sin(j * psi), np.cos(j * psi)]
    return np.column_stack(cols)


def _lsq(A: np.ndarray, y: np.ndarray, sigma: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients and standard errors; sigma stated (known) or the residual scatter."""
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    dof = max(y.size - A.shape[1], 1)
    s2 = float(res @ res) / dof if sigma is None else sigma * sigma
    cov = np.linalg.pinv(A.T @ A) * s2
    return coef, np.sqrt(np.diag(cov))


def _stride(n: int) -> slice:
    return slice(None, None, max(1, math.ceil(n / MAX_SAMPLES)))


def _twin_grating(w: float, delta: float, cfg: TwinConfig) -> np.ndarray:
    """(Zs1 + A0, Zc1, Zs2, Zc2, Zs3, Zc3) the read head sees, from the twin's table motion."""
    psi_a = 2 * math.pi * np.arange(N_PHASES) / N_PHASES
    z = table_position_m(psi_a + w * delta, w, cfg)
    spec = np.fft.rfft(z) / N_PHASES
    out = []
    for j in HARMONICS:
        out += [-2.0 * spec[j].imag, 2.0 * spec[j].real]
    return np.array(out)


def _twin_rate_harmonics(theta: float, f_true: float, delta: float, cfg: TwinConfig) -> np.ndarray:
    """Rate harmonics (sin, cos) per j in the apparent phase, from periodic_rate."""
    pr = periodic_rate(theta, f_true, cfg)
    w = 2 * math.pi * f_true
    out = []
    for j in HARMONICS:
        idx = np.flatnonzero(pr.k == j)
        a, b = (float(pr.alpha[idx[0]]), float(pr.beta[idx[0]])) if idx.size else (0.0, 0.0)
        # r = a cos j psi + b sin j psi, psi = psi_a + w delta: rotate into psi_a.
        ph = j * w * delta
        out += [b * math.cos(ph) - a * math.sin(ph), a * math.cos(ph) + b * math.sin(ph)]
    return np.array(out)


def _phase_se(coef: np.ndarray, w: float, sd_stamp_s: float) -> np.ndarray:
    """se of (Zs1, Zc1, Zs2, ...) from a phase error w sd_stamp of the apparent crank phase."""
    out = np.empty_like(coef)
    for k, j in enumerate(HARMONICS):
        zs, zc = coef[2 * k], coef[2 * k + 1]
        out[2 * k], out[2 * k + 1] = j * w * sd_stamp_s * abs(zc), j * w * sd_stamp_s * abs(zs)
    return out


ROWS_PER_RECORD = 7  # six harmonics and the record's own frequency error


@dataclass(frozen=True)
class GratingRecord:
    """The grating at every vibration point with a raw record: a channel of the fit (station.gap.fit).

    measured[k] = (Zs1 + A0, Zc1, Zs2, Zc2, Zs3, Zc3, eps_g) of point index[k]: the harmonics (m)
    read in the apparent crank phase w_m (t - t_ref), and the frequency error eps_g = w_g / w_cmd - 1
    that the record's own phase drift gives (w_g = w_m + dw, dw the Gauss-Newton step of the phase
    slope (t - t_mid) dz/dpsi, no stamp needed). t_ref is the reference stamp t1, or the mean of
    every stamp of reference_t (each minus its whole periods) when the record has them, which
    cuts the stamp's phase error by sqrt(n). se their standard errors: the least-squares scatter
    (the stated grating noise when session.json gives it, else the fit's own residual, from
    thousands of samples), the phase error of t_ref, and the quantum of an undithered record.
    """

    index: np.ndarray  # point indices
    w_radps: np.ndarray  # from the record's own timing capture
    measured: np.ndarray  # (points, ROWS_PER_RECORD)
    se: np.ndarray  # (points, ROWS_PER_RECORD)

    @property
    def n_rows(self) -> int:
        return int(self.measured.size)

    @classmethod
    def from_session(
        cls, session: Session, design: PointDesign, sd_stamp_s: float, noise_m: float | None = None
    ) -> GratingRecord | None:
        idx, ws, meas, ses = [], [], [], []
        for i, pid in enumerate(design.point_ids):
            raw = session.raw.get(pid)
            if raw is None or not design.vib[i] or raw.grating_t.size <= 20:
                continue
            w = _apparent_w(design, i)
            t_ref, sd_ref = _reference_phase(raw.reference_t, design.t1_s[i], w, sd_stamp_s)
            s = _stride(raw.grating_t.size)
            t, z = raw.grating_t[s], raw.grating_z[s]
            A = _design(w * (t - t_ref))
            coef, se = _lsq(A, z, noise_m)
            floor = grating_floor_m(z, float(np.std(z - A @ coef)))
            se = np.hypot(np.hypot(se[1:], _phase_se(coef[1:], w, sd_ref)), floor)
            # The phase slope: dz/dpsi of the fitted harmonics times (t - t_mid), one Gauss-Newton step in w.
            psi = w * (t - t_ref)
            dz = sum(
                j * (coef[2 * k + 1] * np.cos(j * psi) - coef[2 * k + 2] * np.sin(j * psi))
                for k, j in enumerate(HARMONICS)
            )
            slope = np.column_stack([A, (t - t.mean()) * dz])
            c2, se2 = _lsq(slope, z, noise_m)
            w_cmd = 2 * math.pi * float(design.freq_hz[i])
            eps_g, se_eps = (w + c2[-1]) / w_cmd - 1.0, se2[-1] / w_cmd
            idx.append(i)
            ws.append(w)
            meas.append(np.append(coef[1:], eps_g))
            ses.append(np.maximum(np.append(se, se_eps), 1e-15))
        if not idx:
            return None
        return cls(np.array(idx), np.array(ws), np.array(meas), np.array(ses))

    def predict(self, cfg: TwinConfig) -> np.ndarray:
        """What the twin gives for the same numbers (its table motion, latency, eps_f), point-major."""
        delta = terms.reference_latency_s(cfg.effects)
        eps = terms.frequency_offset(cfg.effects)
        return np.concatenate([np.append(_twin_grating(float(w), delta, cfg), eps) for w in self.w_radps])

    def white(self, values: np.ndarray) -> np.ndarray:
        return values / self.se.ravel()

    def observed_white(self) -> np.ndarray:
        return self.white(self.measured.ravel())


def _reference_phase(
    reference_t: np.ndarray | None, t1_s: float, w_radps: float, sd_stamp_s: float
) -> tuple[float, float]:
    """The crank's psi = 0 time and its sd: t1, or the mean of all reference stamps referred back to t1.

    Grating sample times and stamps share only the window's opening edge, itself a stamp: its error
    adds one stamp's variance to the phase of the grating against the reference marks."""
    if reference_t is None or np.size(reference_t) < 2:
        return float(t1_s), math.sqrt(2.0) * sd_stamp_s
    period = 2 * math.pi / w_radps
    k = np.round((np.asarray(reference_t, dtype=float) - t1_s) / period)
    n = np.size(reference_t)
    return float(np.mean(reference_t - k * period)), sd_stamp_s * math.sqrt(1.0 + 1.0 / n)


def _apparent_w(design: PointDesign, i: int) -> float:
    """w_m = 2 pi Np / (t2 + Tm - t1): the record's own frequency (no model needed)."""
    return 2 * math.pi * int(design.Np[i]) / (design.t2_s[i] + design.Tm_s[i] - design.t1_s[i])


def raw_evidence(session: Session, design: PointDesign, cfg: TwinConfig, sd_stamp_s: float) -> dict:
    """Grating and pulse-rate harmonics of every vibration point with raw streams ({} if none).

    cfg: the twin to compare with, its calibrated coefficients refitted to the session;
    sd_stamp_s: standard deviation of one time stamp (of t1).
    """
    if not session.raw:
        return {}
    points = []
    rows_w, rows_d, rows_s = [], [], []
    delta = terms.reference_latency_s(cfg.effects)
    for i, pid in enumerate(design.point_ids):
        raw = session.raw.get(pid)
        if raw is None or not design.vib[i]:
            continue
        t1 = design.t1_s[i]
        w = _apparent_w(design, i)
        f_true = design.freq_hz[i] * (1 + terms.frequency_offset(cfg.effects))
        entry: dict = {
            "point_id": pid,
            "position_deg": float(design.position_deg[i]),
            "freq_hz": float(design.freq_hz[i]),
            "measured_freq_hz": w / (2 * math.pi),
            "twin_freq_hz": float(f_true),
        }
        if raw.grating_t.size > 20:
            s = _stride(raw.grating_t.size)
            t, z = raw.grating_t[s], raw.grating_z[s]
            A = _design(w * (t - t1))
            coef, se = _lsq(A, z)
            meas = coef[1:]
            floor = grating_floor_m(z, float(np.std(z - A @ coef)))
            se = np.hypot(np.hypot(se[1:], _phase_se(meas, w, sd_stamp_s)), floor)
            pred = _twin_grating(w, delta, cfg)
            diff = meas - pred
            entry["grating"] = {
                n: {"measured_m": float(m), "twin_m": float(p), "difference_m": float(dd), "se_m": float(e)}
                for n, m, p, dd, e in zip(_GRATING_NAMES, meas, pred, diff, se, strict=True)
            }
            rows_w.append(w)
            rows_d.append(diff)
            rows_s.append(se)
        dirs = _pulse_directions(raw, design, i, cfg) if raw.pulse_t.size > 20 else None
        if raw.pulse_t.size > 20 and dirs is None:
            entry["pulse_rate_harmonics"] = (
                "no pulse directions (pulse_dir) and a rate that reverses: the up/down count cannot be rebuilt"
            )
        elif dirs is not None:
            entry["pulse_rate_harmonics"] = _pulse_harmonics(
                raw, dirs, w, t1, session.station.pulses_per_rev, i, design, cfg, sd_stamp_s
            )
        points.append(entry)
    out: dict = {"points": points, "n_points": len(points)}
    if rows_d:
        out["grating_summary"] = _grating_summary(np.array(rows_w), np.array(rows_d), np.array(rows_s))
    return out


def _pulse_directions(raw, design: PointDesign, i: int, cfg: TwinConfig) -> np.ndarray | None:
    """+1/-1 per edge: pulse_dir when recorded, else the precession's sign where the twin's rate never
    reverses over a crank turn (every edge then counts one way); None when it reverses (a > 1 near IA)."""
    if raw.pulse_dir is not None:
        return np.asarray(raw.pulse_dir)
    f_true = design.freq_hz[i] * (1 + terms.frequency_offset(cfg.effects))
    pr = periodic_rate(float(design.theta_rad[i]), float(f_true), cfg)
    psi = 2 * math.pi * np.arange(N_PHASES) / N_PHASES
    rate = pr.c0_radps + sum(
        a * np.cos(k * psi) + b * np.sin(k * psi) for k, a, b in zip(pr.k, pr.alpha, pr.beta, strict=True)
    )
    sign = np.sign(design.rate_radps[i])
    if np.min(sign * rate) <= 0:
        return None
    return np.full(raw.pulse_t.size, int(sign))


def _pulse_fit(raw, dirs: np.ndarray, w: float, t1: float, pulses_per_rev: int, sd_stamp_s: float):
    """Rate harmonics (sin, cos per j) and their se from the precession angle at every pulse edge."""
    fit = _pulse_lsq(raw, dirs, w, t1, pulses_per_rev)
    return fit.meas, np.hypot(fit.se, _phase_se(fit.meas, w, sd_stamp_s))


# Below this fraction of its rms the rate is not trusted to weight an edge (the turning points of a reversing rate).
RATE_WEIGHT_FLOOR = 0.01


def _fitted_rate(coef: np.ndarray, w: float, psi: np.ndarray) -> np.ndarray:
    """d phi / dt of phi0 + c0 t + sum_j (A_j sin j psi + B_j cos j psi) (the columns of _design with a line)."""
    return coef[1] + sum(
        j * w * (coef[2 * k + 2] * np.cos(j * psi) - coef[2 * k + 3] * np.sin(j * psi)) for k, j in enumerate(HARMONICS)
    )


def _walk_cov(Aw: np.ndarray, sd: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, float]:
    """What a random walk of the angle does to the weighted least squares (Aw = A / sd), per unit diffusion D
    (rad^2/s): white rate noise of two-sided density D integrates into phi(t) a walk with cov(W(t_i), W(t_j)) =
    D K_ij, K_ij = min(t_i, t_j) - t_0 (t_0 the first edge: the constant column takes W(t_0)).
    Returns the coefficients' covariance P M^T K M P (M = Aw / sd, P = (Aw^T Aw)^-1; M^T K M = sum_k (t_k -
    t_k-1) C_k C_k^T, C_k = sum_{i >= k} M_i, edges in time order) and the expected weighted residual sum of
    squares E[rss] = tr((I - H) S^-1 K S^-1) = sum_i K_ii / sd_i^2 - tr(P M^T K M) (H the hat matrix, S = diag sd)."""
    P = np.linalg.pinv(Aw.T @ Aw)
    C = np.cumsum((Aw / sd[:, None])[::-1], axis=0)[::-1][1:]
    H = (C * np.diff(t)[:, None]).T @ C
    rss_per_D = float(np.sum((t - t[0]) / sd**2)) - float(np.trace(P @ H))
    return P @ H @ P, max(rss_per_D, 1e-300)


@dataclass(frozen=True)
class PulseFit:
    """One record's rate harmonics (_pulse_lsq): values, se, the random walk's covariance per unit D, and the
    walk's density D that the edges' scatter beyond the stamps' own implies (0 when it implies none)."""

    meas: np.ndarray
    se: np.ndarray
    walk_unit: np.ndarray
    walk_density: float


def _pulse_lsq(
    raw, dirs: np.ndarray, w: float, t1: float, pulses_per_rev: int, tick_s: float = 0.0, sd_stamp_s: float = 0.0
) -> PulseFit:
    """Rate harmonics (sin, cos per j) in the phase w (t - t1), their least-squares se (no phase error) and
    what a random walk of the angle adds to them (_walk_cov).

    An edge's stamp error e_i (jitter and the counter's quantum, independent from edge to edge) puts the angle
    at it off by rate(t_i) e_i: the angle's variance is rate(t_i)^2 var(e), not a constant (a rate that swings
    by its own size makes ordinary least squares' se wrong by factors of 0.4-2 per harmonic). So the fit is
    weighted least squares (Aitken) with weights 1 / rate(t_i)^2 from an ordinary first pass, and the se come
    from the weighted residual scatter, i.e. the stamps' sd in seconds, taken at least tick / sqrt(12) (a
    record whose stamps carry no jitter scatters by its rounding alone). The weighted rss beyond (n - p)
    sd_stamp^2 (a stamp's sd, stated or from the period identities) gives the walk's density by moments,
    D = excess / E[rss per unit D]; none when sd_stamp_s is 0."""
    # The level an edge crosses: the up/down count after it, plus one after a down edge (a
    # down-crossing of level k leaves the count at k - 1); the count alone would add a
    # half-pulse square wave in step with the rate's sign, i.e. spurious odd harmonics.
    levels = np.cumsum(dirs) + (dirs < 0)
    s = _stride(raw.pulse_t.size)
    t = raw.pulse_t[s]
    psi = w * (t - t1)
    A, y = _design(psi, with_line=t), levels[s] * (2 * math.pi / pulses_per_rev)
    coef, _ = _lsq(A, y)
    rate = np.abs(_fitted_rate(coef, w, psi))
    sd = np.maximum(rate, RATE_WEIGHT_FLOOR * math.sqrt(float(np.mean(rate**2))))
    Aw, yw = A / sd[:, None], y / sd
    coef, se = _lsq(Aw, yw)
    dof = max(y.size - A.shape[1], 1)
    rss = float(np.sum((yw - Aw @ coef) ** 2))
    floor = tick_s / math.sqrt(12.0)
    if math.sqrt(rss / dof) < floor:
        se = se * (floor / max(math.sqrt(rss / dof), 1e-300))
    walk_coef, rss_per_D = _walk_cov(Aw, sd, t)
    density = max(rss - dof * max(sd_stamp_s, floor) ** 2, 0.0) / rss_per_D if sd_stamp_s > 0 else 0.0
    # phi = A sin + B cos  ->  rate = j w (A cos - B sin): sin part -j w B, cos part j w A
    jw = np.repeat([j * w for j in HARMONICS], 2)
    to_rate = np.zeros((jw.size, coef.size))  # d meas / d coef
    to_rate[0::2, 3::2] = -np.diag(jw[0::2])
    to_rate[1::2, 2::2] = np.diag(jw[1::2])
    return PulseFit(to_rate @ coef, np.abs(to_rate) @ se, to_rate @ walk_coef @ to_rate.T, density)


def _pulse_prediction(design: PointDesign, i: int, cfg: TwinConfig) -> np.ndarray:
    f_true = design.freq_hz[i] * (1 + terms.frequency_offset(cfg.effects))
    return _twin_rate_harmonics(float(design.theta_rad[i]), f_true, terms.reference_latency_s(cfg.effects), cfg)


def _pulse_harmonics(
    raw, dirs: np.ndarray, w: float, t1: float, pulses_per_rev: int, i: int, design: PointDesign, cfg: TwinConfig,
    sd_stamp_s: float,
) -> list[dict]:  # fmt: skip
    """Rate harmonics from the precession angle at every pulse edge, against the twin's periodic_rate."""
    meas, se_rate = _pulse_fit(raw, dirs, w, t1, pulses_per_rev, sd_stamp_s)
    pred = _pulse_prediction(design, i, cfg)
    return [
        {
            "harmonic": j,
            "measured_radps": float(np.hypot(*meas[2 * k : 2 * k + 2])),
            "twin_radps": float(np.hypot(*pred[2 * k : 2 * k + 2])),
            "difference_radps": float(np.hypot(*(meas - pred)[2 * k : 2 * k + 2])),
            "se_radps": float(np.hypot(*se_rate[2 * k : 2 * k + 2])),
        }
        for k, j in enumerate(HARMONICS)
    ]


@dataclass(frozen=True)
class PulseRecord:
    """The rate harmonics that the pulse edges give at every raw vibration record: a channel of the verdict.

    measured[k] = (S1, C1, S2, C2, S3, C3), the rate's harmonics (rad/s) at point index[k] in the apparent crank
    phase w_m (t - t_ref) (t_ref as for the grating: t1, or the mean of the reference stamps, _reference_phase);
    se their least-squares standard errors (the edges' scatter about the fitted precession angle);
    sd_phase_rad = w_m sd(t_ref), the phase error that a record's harmonics share (harmonic j turned by j e);
    walk_unit the covariance per unit D that a random walk of the precession angle adds (white rate noise, which
    physics.md allows beside a per-window error: its density D is given to `chi2`).
    Records whose up/down count cannot be rebuilt (no pulse_dir and a rate that reverses) are left out.
    The twin's prediction depends on the refitted coefficients and effects: its uncertainty enters the test
    (`chi2`) through their covariance, so the pulses need not be in the fit (they are independent of its rows).
    """

    index: np.ndarray
    w_radps: np.ndarray
    measured: np.ndarray  # (records, 6)
    se: np.ndarray  # (records, 6)
    sd_phase_rad: np.ndarray  # (records,)
    walk_unit: np.ndarray  # (records, 6, 6), per unit D (rad^2/s)
    walk_density: np.ndarray  # (records,), D that each record's scatter beyond its stamps' implies (PulseFit)

    @property
    def n_rows(self) -> int:
        return int(self.measured.size)

    @classmethod
    def from_session(
        cls, session: Session, design: PointDesign, cfg: TwinConfig, sd_stamp_s: float, tick_s: float
    ) -> PulseRecord | None:
        """tick_s: the counter's quantum; every edge is a stamped event, so no edge is timed finer than
        tick / sqrt(12) and the precession angle at it no finer than |rate| tick / sqrt(12) (a floor on the
        edges' scatter, which alone can fall to rounding where a record's stamps carry no jitter)."""
        idx, ws, sds, fits = [], [], [], []
        for i, pid in enumerate(design.point_ids):
            raw = session.raw.get(pid)
            if raw is None or not design.vib[i] or raw.pulse_t.size <= 20:
                continue
            dirs = _pulse_directions(raw, design, i, cfg)
            if dirs is None:
                continue
            w = _apparent_w(design, i)
            t_ref, sd_ref = _reference_phase(raw.reference_t, design.t1_s[i], w, sd_stamp_s)
            fits.append(_pulse_lsq(raw, dirs, w, t_ref, session.station.pulses_per_rev, tick_s, sd_stamp_s))
            idx.append(i)
            ws.append(w)
            sds.append(w * sd_ref)
        if not idx:
            return None
        meas, ses = np.array([f.meas for f in fits]), np.maximum(np.array([f.se for f in fits]), 1e-300)
        walks, density = np.array([f.walk_unit for f in fits]), np.array([f.walk_density for f in fits])
        return cls(np.array(idx), np.array(ws), meas, ses, np.array(sds), walks, density)

    def predict(self, design: PointDesign, cfg: TwinConfig) -> np.ndarray:
        """The twin's rate harmonics at every record (periodic_rate, latency-rotated), record-major."""
        return np.concatenate([_pulse_prediction(design, int(i), cfg) for i in self.index])

    def covariance(self, walk_D: np.ndarray | None = None) -> np.ndarray:
        """Of the measured harmonics: diag(se^2), each record's shared phase error (d/de of a turn by j e) and
        the random walk of its angle at density walk_D[k] (rad^2/s; none when None)."""
        n = self.measured.shape[1]
        C = np.diag(self.se.ravel() ** 2)
        j = np.repeat(np.array(HARMONICS, dtype=float), 2)
        D = np.zeros(len(self.index)) if walk_D is None else walk_D
        for k, (m, sd) in enumerate(zip(self.measured, self.sd_phase_rad, strict=True)):
            g = j * np.column_stack([-m[1::2], m[0::2]]).ravel()  # (S, C) -> (S - j e C, C + j e S)
            C[k * n : (k + 1) * n, k * n : (k + 1) * n] += sd * sd * np.outer(g, g) + D[k] * self.walk_unit[k]
        return C

    def chi2(
        self, design: PointDesign, cfg: TwinConfig, G: np.ndarray, cov_params: np.ndarray, walk_D: np.ndarray
    ) -> float:
        """r^T (C_meas + G Cov G^T)^-1 r of r = measured - predicted, G = d(prediction)/d(fitted parameters);
        walk_D the density of white rate noise at each record (covariance)."""
        r = self.measured.ravel() - self.predict(design, cfg)
        C = self.covariance(walk_D) + G @ cov_params @ G.T
        return float(r @ np.linalg.solve(C, r))


def raw_summary_text(raw: dict, n_se: float = 3.0) -> str:
    """The grating's waveform differences from the twin that exceed n_se standard errors, in words."""
    summary = raw.get("grating_summary", {})
    big = [
        f"{name.removesuffix('_m')} {v['value']:+.3g} ± {v['se']:.2g}"
        for name, v in summary.items()
        if abs(v["value"]) > n_se * v["se"]
    ]
    head = f"raw streams at {raw['n_points']} vibration points"
    if not summary:
        return head + " (no grating record)"
    if big:
        return head + "; grating differs from the twin in " + ", ".join(big)
    return head + f"; grating agrees with the twin within {n_se:g} se"


def _grating_summary(w: np.ndarray, d: np.ndarray, s: np.ndarray) -> dict:
    """Waveform parameters implied by the grating differences (weighted least squares)."""
    out: dict = {}
    s = np.maximum(s, 1e-12)
    wt = 1.0 / s[:, 0] ** 2
    if np.unique(np.round(w, 6)).size >= 2:
        A = np.column_stack([np.ones_like(w), w])
        cov = np.linalg.inv(A.T @ (A * wt[:, None]))
        coef = cov @ (A.T @ (wt * d[:, 0]))
        out["z0_m"] = {"value": float(coef[0]), "se": float(math.sqrt(cov[0, 0]))}
        out["z1_m_s_per_rad"] = {"value": float(coef[1]), "se": float(math.sqrt(cov[1, 1]))}
    else:
        out["Zs1_m"] = {"value": float(np.average(d[:, 0], weights=wt)), "se": float(1 / math.sqrt(wt.sum()))}
    for k, name in enumerate(_GRATING_NAMES[1:], start=1):
        wk = 1.0 / s[:, k] ** 2
        out[f"{name}_m"] = {
            "value": float(np.average(d[:, k], weights=wk)),
            "se": float(1 / math.sqrt(wk.sum())),
            "note": "Zc1 includes the read-head latency phase A0 w delta" if name == "Zc1" else "",
        }
    return out
