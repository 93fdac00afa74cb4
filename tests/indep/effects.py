"""Effects as perturbations of the independent world, their signatures, and SNR scaling.

Library effects are physics.md's table; out-of-library effects are causes that table does not
name (a diagnosis must never call them `explained`). Each effect draws physically plausible
parameters (index-head errors of arcseconds, waveform errors of micrometres, ...) and knows which
of them scale its strength.

Signature and SNR. A session's channels are
- `static_rates`: static mean rates w = sign 2 pi P / (16384 Tm) minus physics.md's static model
  with the calibrated coefficients (seed 003 form, earth rate included), whitened by each window's
  rate sd; calibration absorbs the columns 1, c, c^2, c^3 (c = cos theta: k0 + ky, kz, kzz - ky, k3);
- `vibration_rates`: every mean rate minus the model's window-mean prediction from the stated t1,
  t2, Tm (closed-form <s>, <s^2>, <s^3> of physics.md, commanded frequency); calibration absorbs a
  level per position (k0 per position) and the partial derivatives in kz, kzz, ky, k3;
- `period_identity`: t1 + Np T - Tm - t2 (T commanded), whitened by sqrt(2 (sigma_t^2 + tick^2/12))
  (it is the difference of two reference stamps); nothing is absorbed;
- `grating` (only with raw records): z(t) minus the nominal A0 sin(w_cmd (t - t1)) at the 5 kHz
  sample times, whitened by the grating noise; a constant per record (zbar) is absorbed.
An effect's signature on a channel is that residual vector of the noise-free session with the
effect (no rate noise, no jitter, no ticks; the same crank phases and waits as the written
session), and SNR = sqrt(sum (r_i / sigma_i)^2) of the part of it orthogonal to the absorbed
columns (weighted least squares projection). The effect's channel is the available channel on
which its drawn parameters give the largest SNR; `scale_to_snr` multiplies the effect's strength
parameters until that SNR equals the request (power-law secant iteration to 0.1 %; where a first
passage moves by a whole period as the strength changes, SNR(strength) has small steps and the
nearest value found, within a few %, is kept: the truth's snr_achieved states it). No effect is made
stronger than its plausible bounds (STRENGTH_CAP = 1: a diagnosis that bounds each effect by plausible
magnitudes, issue 10 item 2, must not be scored on effects beyond them): where a design cannot show an
effect within them, the SNR reached is below the request (snr_achieved says so). For +-1 pulse
miscounts, a discrete effect, windows are miscounted one by one (random order) until the SNR
reaches the request, so the SNR achieved is the nearest the windows allow.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from indep.generator import Design, Draws, Noise, Row, Truth, simulate
from indep.world import A0_M, ARCSEC_RAD, EARTH_RATE_RADPS, LATITUDE_DEG, PULSE_RAD, Perturbation

UM = 1e-6
STRENGTH_CAP = 1.0  # scale_to_snr never makes an effect stronger than this many times its plausible bounds
CHANNELS = ("static_rates", "vibration_rates", "period_identity", "grating")


@dataclass(frozen=True)
class Effect:
    """One cause: its parameters (drawn), which of them scale its strength, and how it changes the world."""

    name: str
    in_library: bool
    draw: Callable[[np.random.Generator, Context], dict[str, float]]
    apply: Callable[[Truth, dict[str, float]], Truth]
    scaled: tuple[str, ...]
    bounds: dict[str, float] = field(default_factory=dict)  # plausible |value| per parameter
    power: float = 1.0  # SNR grows about as (strength scale)^power


@dataclass
class Context:
    """What scaling needs: the design, the base truth (no effect), its draws and plan, nominal rows."""

    design: Design
    truth: Truth
    draws: Draws
    plan: list
    raw: bool
    rows0: list[Row] = field(default_factory=list)

    @property
    def session_s(self) -> float:
        r = self.rows0[-1]
        return r.start_s + r.true_Tm_s


def _lu(rng: np.random.Generator, lo: float, hi: float, signed: bool = True) -> float:
    x = math.exp(rng.uniform(math.log(lo), math.log(hi)))
    return -x if signed and rng.random() < 0.5 else x


def _pe(**kw: object) -> Callable[[Truth, dict[str, float]], Truth]:
    """apply() that sets Perturbation fields from parameters: kw maps field -> parameter name (or tuple)."""

    def apply(truth: Truth, p: dict[str, float]) -> Truth:
        upd = {f: (tuple(p[n] for n in k) if isinstance(k, tuple) else p[k]) for f, k in kw.items()}
        return truth.with_(pe=replace(truth.pe, **upd))

    return apply


def _co(**kw: str) -> Callable[[Truth, dict[str, float]], Truth]:
    def apply(truth: Truth, p: dict[str, float]) -> Truth:
        return truth.with_(co=replace(truth.co, **{f: p[k] for f, k in kw.items()}))

    return apply


def _apply_lateral(truth: Truth, p: dict[str, float]) -> Truth:
    pe = replace(truth.pe, L0=p["L0"], fr_hz=p["fr_hz"], Q=p["Q"], phiL_rad=p["phiL_rad"])
    return truth.with_(co=replace(truth.co, kx=p["kx"]), pe=pe)


def _draw_lateral(rng: np.random.Generator, ctx: Context) -> dict[str, float]:
    fmax = max(ctx.design.freqs_hz)
    while True:
        p = {
            "L0": _lu(rng, 1e-3, 1e-2, False),
            "fr_hz": float(rng.uniform(0.7, 2.0) * fmax),
            "Q": float(rng.uniform(3.0, 20.0)),
            "phiL_rad": float(rng.uniform(0.0, 2 * math.pi)),
            "kx": _lu(rng, 5e-6, 5e-5),
        }
        gain = Perturbation(L0=p["L0"], fr_hz=p["fr_hz"], Q=p["Q"]).lateral_gain
        if max(gain(f) for f in ctx.design.freqs_hz) <= 0.1:  # lateral motion at most 10 % of vertical
            return p


def _draw_miscount(rng: np.random.Generator, ctx: Context) -> dict[str, float]:
    return {"order_seed": float(rng.integers(0, 2**31)), "n_miscounted": 1.0}


def _apply_miscount(truth: Truth, p: dict) -> Truth:
    """The counter closes windows +-1 pulse off the count it reports: p["points"] = {index: +-1}."""
    t = copy.copy(truth)
    t.miscount = {int(k): int(v) for k, v in p.get("points", {}).items()}
    return t


def _draw_jitter(rng: np.random.Generator, ctx: Context) -> dict[str, float]:
    return {
        "scale_s": 1e-6,
        "df": float(rng.uniform(1.2, 2.5)),
        "p_outlier": float(rng.uniform(0.05, 0.3)),
        "pattern_seed": float(rng.integers(0, 2**31)),
        "n_windows": float(len(ctx.plan)),
    }


def _apply_jitter(truth: Truth, p: dict[str, float]) -> Truth:
    """Reference stamps get extra Student-t jitter (scale_s, df) with probability p_outlier."""
    n = int(p["n_windows"])
    rng = np.random.default_rng(int(p["pattern_seed"]))
    hit = rng.random((int(n), 2)) < p["p_outlier"]
    t = copy.copy(truth)
    t.jitter_outliers_s = np.where(hit, p["scale_s"] * rng.standard_t(p["df"], (int(n), 2)), 0.0)
    return t


def _apply_step(truth: Truth, p: dict[str, float]) -> Truth:
    return truth.with_(pe=replace(truth.pe, step_radps=p["b_radps"], step_time_s=p["t_step_s"]))


def _draw_step(rng: np.random.Generator, ctx: Context) -> dict[str, float]:
    return {"b_radps": _lu(rng, 1e-6, 2e-5), "t_step_s": float(rng.uniform(0.3, 0.7) * ctx.session_s)}


def _idx_apply(truth: Truth, p: dict[str, float]) -> Truth:
    c = tuple(p[f"c{k}_rad"] for k in range(1, 5))
    s = tuple(p[f"s{k}_rad"] for k in range(1, 5))
    return truth.with_(pe=replace(truth.pe, idx_c_rad=c, idx_s_rad=s))


def _idx_draw(rng: np.random.Generator, ctx: Context) -> dict[str, float]:
    return {f"{cs}{k}_rad": _lu(rng, 0.5, 5.0) * ARCSEC_RAD for k in range(1, 5) for cs in "cs"}


_AS = ARCSEC_RAD
EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect(
            "waveform_fundamental",
            True,
            lambda r, c: {"z0_m": _lu(r, 2, 30) * UM, "z1_ms": _lu(r, 0.05, 0.5) * UM, "zc1_m": _lu(r, 2, 30) * UM},
            _pe(z0_m="z0_m", z1_ms="z1_ms", zc1_m="zc1_m"),
            ("z0_m", "z1_ms", "zc1_m"),
            {"z0_m": 100 * UM, "z1_ms": 2 * UM, "zc1_m": 100 * UM},
        ),
        Effect(
            "waveform_harmonics",
            True,
            lambda r, c: {k: _lu(r, 0.5, 10) * UM for k in ("zs2_m", "zc2_m", "zs3_m", "zc3_m")},
            _pe(zs2_m="zs2_m", zc2_m="zc2_m", zs3_m="zs3_m", zc3_m="zc3_m"),
            ("zs2_m", "zc2_m", "zs3_m", "zc3_m"),
            {k: 50 * UM for k in ("zs2_m", "zc2_m", "zs3_m", "zc3_m")},
        ),
        Effect(
            "parasitic_rotation",
            True,
            lambda r, c: {k: _lu(r, 1, 20) * _AS for k in ("ax0_rad", "axs1_rad", "axc1_rad")},
            _pe(ax0_rad="ax0_rad", axs1_rad="axs1_rad", axc1_rad="axc1_rad"),
            ("ax0_rad", "axs1_rad", "axc1_rad"),
            {k: 60 * _AS for k in ("ax0_rad", "axs1_rad", "axc1_rad")},
        ),
        Effect(
            "lateral_resonance",
            True,
            _draw_lateral,
            _apply_lateral,
            ("L0", "kx"),
            {"L0": 0.05, "kx": 2e-4},
            3.0,
        ),
        Effect(
            "odd_quadratic", True, lambda r, c: {"koq": _lu(r, 2e-6, 3e-5)}, _co(koq="koq"), ("koq",), {"koq": 1e-4}
        ),
        Effect(
            "cross_coupling", True, lambda r, c: {"kip": _lu(r, 2e-6, 3e-5)}, _co(kip="kip"), ("kip",), {"kip": 1e-4}
        ),
        Effect(
            "index_harmonics",
            True,
            _idx_draw,
            _idx_apply,
            tuple(f"{cs}{k}_rad" for k in range(1, 5) for cs in "cs"),
            {f"{cs}{k}_rad": 20 * _AS for k in range(1, 5) for cs in "cs"},
        ),
        Effect(
            "mount_misalignment",
            True,
            lambda r, c: {"dtheta_mount_rad": _lu(r, 5, 60) * _AS},
            _pe(mount_rad="dtheta_mount_rad"),
            ("dtheta_mount_rad",),
            {"dtheta_mount_rad": 300 * _AS},
        ),
        Effect(
            "bias_drift",
            True,
            lambda r, c: {"d_radps_per_s": _lu(r, 1e-10, 1e-8)},
            _pe(drift_radps_per_s="d_radps_per_s"),
            ("d_radps_per_s",),
            {"d_radps_per_s": 1e-7},
        ),
        Effect(
            "readhead_latency",
            True,
            lambda r, c: {"delta_s": _lu(r, 1e-6, 1e-4, False)},
            _pe(latency_s="delta_s"),
            ("delta_s",),
            {"delta_s": 1e-3},
        ),
        Effect(
            "frequency_error",
            True,
            lambda r, c: {"eps_f": _lu(r, 1e-6, 1e-4)},
            _pe(eps_f="eps_f"),
            ("eps_f",),
            {"eps_f": 5e-4},
        ),
        # ---- out of library ----
        Effect(
            "scale_asymmetry",
            False,
            lambda r, c: {"kz_asym": _lu(r, 1e-5, 1e-3)},
            _co(kz_asym="kz_asym"),
            ("kz_asym",),
            {"kz_asym": 1e-2},
        ),
        Effect("bias_step", False, _draw_step, _apply_step, ("b_radps",), {"b_radps": 1e-4}),
        Effect(
            "quadratic_drift",
            False,
            lambda r, c: {"q_radps_per_s2": _lu(r, 1e-15, 1e-13)},
            _pe(quad_radps_per_s2="q_radps_per_s2"),
            ("q_radps_per_s2",),
            {"q_radps_per_s2": 1e-11},
        ),
        Effect(
            "thermal_transient",
            False,
            lambda r, c: {"b_radps": _lu(r, 1e-6, 2e-5), "tau_s": float(r.uniform(100.0, 1200.0))},
            _pe(transient_radps="b_radps", transient_tau_s="tau_s"),
            ("b_radps",),
            {"b_radps": 1e-4},
        ),
        Effect("pulse_miscount", False, _draw_miscount, _apply_miscount, (), {}),
        Effect("heavy_tailed_jitter", False, _draw_jitter, _apply_jitter, ("scale_s",), {"scale_s": 1e-4}),
        Effect(
            "freq_error_f2",
            False,
            lambda r, c: {"eps_f2_at10hz": _lu(r, 1e-6, 1e-4)},
            _pe(eps_f2_at10hz="eps_f2_at10hz"),
            ("eps_f2_at10hz",),
            {"eps_f2_at10hz": 5e-4},
        ),
        Effect(
            "table_tilt_2psi",
            False,
            lambda r, c: {"ax2s_rad": _lu(r, 1, 20) * _AS, "ax2c_rad": _lu(r, 1, 20) * _AS},
            _pe(ax2s_rad="ax2s_rad", ax2c_rad="ax2c_rad"),
            ("ax2s_rad", "ax2c_rad"),
            {"ax2s_rad": 60 * _AS, "ax2c_rad": 60 * _AS},
        ),
        Effect(
            "index_backlash",
            False,
            lambda r, c: {"backlash_rad": _lu(r, 2, 20) * _AS},
            _pe(backlash_rad="backlash_rad"),
            ("backlash_rad",),
            {"backlash_rad": 60 * _AS},
        ),
        Effect(
            "scale_factor_drift",
            False,
            lambda r, c: {"ks_per_s": _lu(r, 1e-11, 1e-9)},
            _pe(kz_drift_per_s="ks_per_s"),
            ("ks_per_s",),
            {"ks_per_s": 1e-8},
        ),
        Effect("quartic_term", False, lambda r, c: {"k4": _lu(r, 1e-8, 1e-7)}, _co(k4="k4"), ("k4",), {"k4": 1e-6}),
    ]
}
LIBRARY = tuple(n for n, e in EFFECTS.items() if e.in_library)
OUT_OF_LIBRARY = tuple(n for n, e in EFFECTS.items() if not e.in_library)


# ---- signatures ------------------------------------------------------------------------------------------
def window_means(f_hz: float, t1_s: float, t2_s: float, tm_s: float) -> tuple[float, float, float]:
    """<s>, <s^2>, <s^3> over [0, Tm] with s = sin w (t - t1) (physics.md closed forms, seed 000)."""
    w = 2 * math.pi * f_hz
    d1 = math.cos(w * t1_s) - math.cos(w * t2_s)
    d2 = math.sin(2 * w * t1_s) - math.sin(2 * w * t2_s)
    d3 = math.cos(3 * w * t1_s) - math.cos(3 * w * t2_s)
    return d1 / (w * tm_s), 0.5 - d2 / (4 * w * tm_s), (9 * d1 - d3) / (12 * w * tm_s)


def _vib_terms(row: Row) -> tuple[float, np.ndarray]:
    """Nominal prediction's fixed part and its partial derivatives in (k0, kz, kzz, ky, k3) at a row."""
    th = math.radians(row.position_deg)
    c, sn = math.cos(th), math.sin(th)
    lat = math.radians(LATITUDE_DEG)
    earth = -EARTH_RATE_RADPS * math.sin(lat - th)
    if not row.freq_hz:
        return earth, np.array([1.0, c, c * c, 1 - c * c, c**3])
    assert row.t1_s is not None and row.t2_s is not None
    m1, m2, m3 = window_means(row.freq_hz, row.t1_s, row.t2_s, row.Tm_s)
    a = A0_M * (2 * math.pi * row.freq_hz) ** 2 / 9.8016093
    q2 = 1 - 2 * a * m1 + a * a * m2
    q3 = 1 - 3 * a * m1 + 3 * a * a * m2 - a**3 * m3
    return earth, np.array([1.0, c * (1 - a * m1), c * c * q2, sn * sn * q2, c**3 * q3])


def _measured(row: Row) -> float:
    return row.pulses * PULSE_RAD / row.Tm_s


@dataclass
class Signature:
    """Residual vector and absorbed columns of each available channel, both whitened."""

    r: dict[str, np.ndarray]
    X: dict[str, np.ndarray]

    def snr(self, ch: str) -> float:
        r, X = self.r[ch], self.X[ch]
        if r.size == 0:
            return 0.0
        if X.shape[1]:
            r = r - X @ np.linalg.lstsq(X, r, rcond=None)[0]
        return float(np.linalg.norm(r))


def signature(ctx: Context, truth: Truth) -> Signature:
    """Noise-free residuals of the session with `truth` against the nominal model (module docstring)."""
    rows = simulate(ctx.design, truth, ctx.draws, ctx.plan)
    base = ctx.truth.co
    coef = np.array([base.k0, base.kz, base.kzz, base.ky, base.k3])
    noise = ctx.truth.noise
    assert noise is not None
    sd = np.array([ctx.truth.noise.rate_sd(tm) if noise else 1.0 for (_, _, tm) in ctx.plan])
    res, parts = [], []
    for row in rows:
        fixed, d = _vib_terms(row)
        res.append(_measured(row) - fixed - d @ coef)
        parts.append(d)
    res_a, D = np.array(res) / sd, np.array(parts) / sd[:, None]
    static = np.array([not r.freq_hz for r in rows])
    pos = sorted({r.position_deg for r in rows})
    ind = np.array([[r.position_deg == p for p in pos] for r in rows], dtype=float) / sd[:, None]
    cs = np.cos(np.radians([r.position_deg for r in rows]))
    Xs = np.stack([np.ones_like(cs), cs, cs**2, cs**3], axis=1)[static] / sd[static, None]
    r_out = {"static_rates": res_a[static], "vibration_rates": res_a}
    X_out = {"static_rates": Xs, "vibration_rates": np.concatenate([ind, D[:, 1:]], axis=1)}
    vib = [r for r in rows if r.freq_hz]
    ident = [(r.t1_s + r.Np / r.freq_hz - r.Tm_s - r.t2_s) for r in vib]  # type: ignore[operator]
    r_out["period_identity"] = np.array(ident) / noise.identity_sd()
    X_out["period_identity"] = np.zeros((len(vib), 0))
    if ctx.raw and ctx.draws.raw_points:
        r_out["grating"], X_out["grating"] = _grating_channel(ctx, rows, noise)
    return Signature(r_out, X_out)


def _grating_channel(ctx: Context, rows: list[Row], noise: Noise) -> tuple[np.ndarray, np.ndarray]:
    """Grating residual z(t) - A0 sin(w_cmd (t - t1)) of every raw record, whitened, and what it cannot fix.

    Absorbed per record: a constant (zbar) and the phase of the reference: t1 is the difference of two
    stamps (the window's opening edge and the first crossing; physics.md: timing uncertainty about
    1e-7 s), so a shift e of t1 with sd s_ref = noise.identity_sd() moves the nominal model by
    e A0 w cos(w (t - t1)). That shift is marginalised (generalised least squares with the covariance
    sigma_g^2 I + s_ref^2 v v^T), written as one column v / sigma_g and one prior row 0 = e / s_ref, so
    that a latency or a frequency error is not credited with a phase finer than the stamps give.
    """
    blocks: list[tuple[np.ndarray, np.ndarray | None]] = []
    sg, s_ref = noise.grating_noise_m, noise.identity_sd()
    for k, i in enumerate(ctx.draws.raw_points):
        row = rows[i]
        length = min(ctx.draws.raw_len_s, row.true_Tm_s)
        u = float(ctx.draws.raw_u[k])
        t_a = row.true_Tm_s - length if u < 0 else u * (row.true_Tm_s - length)
        t = np.arange(t_a, t_a + length, 1.0 / 5000.0)
        if row.freq_hz:
            w = 2 * math.pi * row.freq_hz
            dz = row.window.z_m(t) - A0_M * np.sin(w * (t - row.t1_s))  # type: ignore[operator]
            blocks.append((dz / sg, A0_M * w * np.cos(w * (t - row.t1_s)) / sg))  # type: ignore[operator]
        else:
            blocks.append((row.window.z_m(t) / sg, None))
    n_phase = sum(v is not None for _, v in blocks)
    n = sum(z.size for z, _ in blocks) + n_phase
    r, X = np.zeros(n), np.zeros((n, len(blocks) + n_phase))
    o, col, prior = 0, len(blocks), n - n_phase
    for j, (z, v) in enumerate(blocks):
        r[o : o + z.size] = z
        X[o : o + z.size, j] = 1.0 / sg
        if v is not None:
            X[o : o + z.size, col] = v
            X[prior, col] = 1.0 / s_ref
            col, prior = col + 1, prior + 1
        o += z.size
    return r, X


def combined(sig: Signature, ctx: Context) -> np.ndarray:
    """All channels stacked, each with what a global calibration absorbs removed (for separability)."""
    out = []
    for ch in ("vibration_rates", "period_identity", "grating"):
        if ch not in sig.r:
            continue
        r, X = sig.r[ch], sig.X[ch]
        if ch == "vibration_rates":  # global k0..k3, not a level per position: static levels must not absorb
            X = X[:, -4:]
            X = np.concatenate([X, _k0_column(ctx)], axis=1)
        if X.shape[1]:
            r = r - X @ np.linalg.lstsq(X, r, rcond=None)[0]
        out.append(r)
    return np.concatenate(out)


def _k0_column(ctx: Context) -> np.ndarray:
    noise = ctx.truth.noise
    assert noise is not None
    return np.array([[1.0 / noise.rate_sd(tm)] for (_, _, tm) in ctx.plan])


# ---- scaling ---------------------------------------------------------------------------------------------
def scale_params(effect: Effect, params: dict[str, float], lam: float) -> dict[str, float]:
    return {k: (v * lam if k in effect.scaled else v) for k, v in params.items()}


def with_effect(truth: Truth, effect: Effect, params: dict[str, float]) -> Truth:
    return effect.apply(truth, params)


def scale_to_snr(
    effect: Effect, params: dict[str, float], snr: float, ctx: Context, truth: Truth | None = None
) -> tuple[dict[str, float], str, float]:
    """Scale the effect's strength so that its SNR on its channel equals snr (module docstring).

    truth: the world the effect is added to (default the context's base truth). Returns the scaled
    parameters, the channel and the SNR reached.
    """
    if not snr > 0:
        raise ValueError(f"snr={snr}: must be > 0")
    base = truth if truth is not None else ctx.truth
    if effect.name == "pulse_miscount":
        return _scale_miscount(params, snr, ctx, base)
    # the strongest the effect may be made: STRENGTH_CAP times its plausible bounds
    caps = [STRENGTH_CAP * effect.bounds[k] / abs(v) for k, v in params.items() if k in effect.scaled and v]
    lam_max = min(caps) if caps else math.inf
    sig = signature(ctx, with_effect(base, effect, params))
    unit = {ch: sig.snr(ch) for ch in sig.r}
    lam_probe = 1.0
    if max(unit.values()) < 1.0 and math.isfinite(lam_max):
        # too weak to tell its channel from rounding (~1e-2): look again at the strongest allowed
        lam_probe = lam_max
        sig = signature(ctx, with_effect(base, effect, scale_params(effect, params, lam_probe)))
        unit = {ch: sig.snr(ch) for ch in sig.r}
    channel = max(unit, key=lambda ch: unit[ch])
    if unit[channel] == 0.0:
        raise ValueError(f"effect {effect.name}: no signature on any channel of this design")
    # power-law secant: SNR ~ lam^p near the solution (p = 1 for most effects, 3 for L0 and kx together)
    lam_prev, s_prev, power = lam_probe, unit[channel], effect.power
    lam = min(lam_prev * (snr / s_prev) ** (1.0 / power), lam_max)
    best = (math.inf, lam_prev, s_prev)
    for _ in range(12):
        s = signature(ctx, with_effect(base, effect, scale_params(effect, params, lam))).snr(channel)
        best = min(best, (abs(s - snr), lam, s))
        if abs(s - snr) <= 1e-3 * snr or (lam >= lam_max and s < snr):
            break
        if s > 0 and s_prev > 0 and lam != lam_prev and s != s_prev:
            # SNR(lam) has small steps (a first passage moves by whole periods as the strength changes):
            # keep the exponent near the effect's own and the step damped
            power = min(max(math.log(s / s_prev) / math.log(lam / lam_prev), 0.5 * effect.power), 2 * effect.power)
        lam_prev, s_prev = lam, s
        lam = min(lam * (snr / s) ** (1.0 / power) if s > 0 else lam * 10.0, lam_max)
    _, lam, s = best
    return scale_params(effect, params, lam), channel, s


def _scale_miscount(
    params: dict[str, float], snr: float, ctx: Context, base: Truth
) -> tuple[dict[str, float], str, float]:
    """Miscount windows one by one (random order, random sign) until the SNR reaches snr.

    A miscount changes only its own window's rate (and the later start times by one pulse time,
    negligibly), so the SNR of each subset is computed from the per-window changes of one session
    with every window miscounted; the chosen subset is then simulated for the SNR reached.
    """
    rng = np.random.default_rng(int(params["order_seed"]))
    order = rng.permutation(len(ctx.plan))
    signs = rng.choice([-1, 1], len(ctx.plan))
    every = copy.copy(base)
    every.miscount = {i: int(signs[i]) for i in range(len(ctx.plan))}
    s_all, s_0 = signature(ctx, every), signature(ctx, base)
    chosen: dict[int, int] = {}
    static = np.array([not p.freq_hz for (p, _, _) in ctx.plan])
    delta = s_all.r["vibration_rates"] - s_0.r["vibration_rates"]
    mask = np.zeros(len(ctx.plan))
    for i in order:
        mask[i] = 1.0
        chosen[int(i)] = int(signs[i])
        trial = Signature(
            {
                "static_rates": s_0.r["static_rates"] + (delta * mask)[static],
                "vibration_rates": s_0.r["vibration_rates"] + delta * mask,
            },
            {k: s_0.X[k] for k in ("static_rates", "vibration_rates")},
        )
        if max(trial.snr("static_rates"), trial.snr("vibration_rates")) >= snr:
            break
    final = copy.copy(base)
    final.miscount = dict(chosen)
    sig = signature(ctx, final)
    channel = max(("static_rates", "vibration_rates"), key=lambda ch: sig.snr(ch))
    p = dict(params)
    p["n_miscounted"] = float(len(chosen))
    p["points"] = {str(k): v for k, v in chosen.items()}  # type: ignore[assignment]
    return p, channel, sig.snr(channel)
