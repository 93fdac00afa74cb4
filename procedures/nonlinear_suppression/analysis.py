"""Seed 004's suppression of the quadratic term: the offset sweep, its spline and minimum, eqs. 21-22, the report.

A session of `nonlinear_suppression` holds calibrations: groups of integral precession points (seed 000,
identified by `procedures.integral_precession.identify`) whose ids start with a group prefix, each after a
`servo_offset`
measurement that names the prefix, the digital offset in force and the stage (sweep, best offset, after the mass
removal). K2 in 1/g0 is kzz / kz, as the seed quotes it. Calibrations of one design and window length (the
sweep's; those at the best offset) share one residual sigma, pooled over them.

The sweep (section 5.1): K2 at each offset, a cubic spline through them evaluated every 0.001" (step 1), then a
bounded line search around the lowest grid value (step 2). The seed interpolates; so does this, and the
uncertainties of the best offset and of K2 there come from redrawing every K2 within its sigma (for the best
offset a conservative figure, about 1.3 x the scatter of repeated sweeps of the twin: redrawing around noisy
calibrations roughens the curve's narrow bottom a second time). A chi^2-smoothing spline (s = n) was tried and
rejected: with 0.5" steps it cannot follow the curve's narrow bottom and puts the minimum 3e-7/g0 too high.
The correction (section 5.2): the inertia product from K2 calibrated at the best offset (eq. 21) and the mass to
remove at each of four points (eq. 22).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace

import matplotlib.pyplot as plt
import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar

from procedures.common.certificate import budget_rows
from procedures.common.uncertainty import Budget, merged_json, type_a_json
from procedures.integral_precession.identify import identify
from station.htmlkit import document, esc, mapping_table, svg, table
from station.least_squares import FitError
from station.records import Field, declare
from station.session import Measurement, PointRecord, Session, StationInfo
from station.twin import nonlinear_error as ne
from station.twin.regressors import COEFFICIENTS, baseline_regressors

SERVO_OFFSET_KIND = "servo_offset"
declare(
    SERVO_OFFSET_KIND,
    [Field("prefix", "str", doc="the calibration group"), Field("stage", "str"),
     Field("offset_arcsec", "float64", "arcsec"), Field("servo", "str", doc="servo state"),
     Field("beta_error_arcsec", "float64", "arcsec")],
    doc="the angle servo's digital offset, read back before a calibration group (seed 004 section 5.1)",
)  # fmt: skip
SWEEP, AT_BEST, AFTER_REMOVAL = "sweep", "best offset", "after mass removal"
GRID_STEP_ARCSEC = 0.001  # seed 004 section 5.1, step 1
MC_DRAWS = 400
MC_SEED = 4


@dataclass(frozen=True)
class Calibration:
    """One integral precession calibration at one digital offset.

    `unit_cov` is the covariance of (kz, kzz) per unit residual variance, (var kz, cov, var kzz); the sigmas
    use `noise_radps`: the calibration's own residual sigma, or one pooled over calibrations that share it.
    """

    prefix: str
    stage: str
    offset_arcsec: float
    kz: float
    kzz: float
    unit_cov: tuple[float, float, float]
    sigma_residual_radps: float
    dof: int
    n_points: int
    mu: float
    mu_c: float
    noise_radps: float
    noise_dof: int = 0  # dof of noise_radps: the pooled sum, or 0 for the calibration's own (then `dof`)

    @property
    def sigma_kzz(self) -> float:
        return math.sqrt(self.unit_cov[2]) * self.noise_radps

    @property
    def k2_per_g(self) -> float:
        """kzz / kz: seed 004's K2 in 1/g0."""
        return self.kzz / self.kz

    @property
    def sigma_k2_per_g(self) -> float:
        a, b = -self.kzz / self.kz**2, 1.0 / self.kz
        c_kz, c_x, c_kzz = self.unit_cov
        return math.sqrt(a * a * c_kz + 2 * a * b * c_x + b * b * c_kzz) * self.noise_radps

    def to_json(self) -> dict:
        return asdict(self) | {"sigma_kzz": self.sigma_kzz, "k2_per_g": self.k2_per_g,
                               "sigma_k2_per_g": self.sigma_k2_per_g}  # fmt: skip


def calibrate(
    station: StationInfo, points: Sequence[PointRecord], prefix: str, stage: str, offset_arcsec: float
) -> Calibration:
    """kz and kzz of one group of points by integral precession (seed 000 eqs. 19-22)."""
    r = identify(Session(station, list(points)))
    i, j = r.names.index("kz"), r.names.index("kzz")
    unit = r.cov / r.sigma_residual**2
    return Calibration(prefix, stage, offset_arcsec, float(r.values[i]), float(r.values[j]),
                       (float(unit[i, i]), float(unit[i, j]), float(unit[j, j])), r.sigma_residual, r.dof,
                       len(points), r.mu_eq28, r.mu_c_eq28, r.sigma_residual)  # fmt: skip


SEED004_TYPE_B = (
    "Type A at the pooled rate noise (its dof); Type B by refit (procedures.nonlinear_suppression.budget): each "
    "calibration's "
    "seed-000 inputs (Zs1, axs1, eps_f, A0, g, read-head latency, latitude, second harmonic) and, for the mass, "
    "H, b and theta of eqs. 21-22"
)
SEED004_TYPE_A_ONLY = (
    "Type A only (k from Student's t at the dof of the pooled rate noise): the session has no calibration at the "
    "best offset nor after the removal, whose budget carries the Type B inputs"
)


def pooled(cals: Sequence[Calibration]) -> list[Calibration]:
    """The calibrations with one residual sigma pooled over them all: sqrt(sum dof s^2 / sum dof).

    For calibrations of one design and window length (the sweep's; those at the best offset), which see the
    same rate noise: a calibration's own sigma has only n - p = 5 degrees of freedom (seed 000 eq. 21).
    """
    dof = sum(c.dof for c in cals)
    noise = math.sqrt(sum(c.dof * c.sigma_residual_radps**2 for c in cals) / dof) if dof else math.nan
    return [replace(c, noise_radps=noise, noise_dof=dof) for c in cals]


def calibrations(session: Session) -> list[Calibration]:
    """Every calibration of the session, in order; noise pooled over the sweep and over the rest."""
    out = []
    for m in session.measurements:
        if m.kind != SERVO_OFFSET_KIND:
            continue
        prefix = m.values["prefix"]
        points = [p for p in session.points if p.point_id.startswith(prefix + "-")]
        if points:
            out.append(calibrate(session.station, points, prefix, m.values["stage"], m.values["offset_arcsec"]))
    by_prefix = {c.prefix: c for c in pooled([c for c in out if c.stage == SWEEP])}
    by_prefix |= {c.prefix: c for c in pooled([c for c in out if c.stage != SWEEP])}
    return [by_prefix[c.prefix] for c in out]


def design_defect(station: StationInfo, positions_deg: Sequence[float], freqs_hz: Sequence[float]) -> str | None:
    """Why a calibration of these positions and frequencies (each with a static test) cannot identify kzz, or None.

    The joint fit has a static level per position and kz, kzz, ky, k3; kz rests on the window-edge terms, the
    other three on the a^2 <s^2> terms, whose columns (seed 000 eq. 35) must be independent.
    """
    n_pos, n_freq = len(set(positions_deg)), len(set(freqs_hz))
    if n_pos * n_freq <= len(COEFFICIENTS):
        return f"{n_pos} positions x {n_freq} frequencies: at least {len(COEFFICIENTS) + 1} vibration points"
    theta, f = np.meshgrid(np.radians(positions_deg), freqs_hz)
    columns = baseline_regressors(theta.ravel(), station.amplitude_ratio(f.ravel()))
    if np.linalg.matrix_rank(columns / np.abs(columns).max(axis=0).clip(1e-300)) < columns.shape[1]:
        return "positions whose cos(theta), cos^2 and sin^2 do not separate kzz, ky and k3 (e.g. 0, 180, 60 deg)"
    return None


@dataclass(frozen=True)
class SweepFit:
    """The spline through K2(offset) and its minimum (seed 004 section 5.1, Fig. 10)."""

    offsets_arcsec: np.ndarray
    k2_per_g: np.ndarray
    sigma_k2_per_g: np.ndarray
    best_offset_arcsec: float  # spline and line search
    sigma_best_offset_arcsec: float
    k2_min_per_g: float
    sigma_k2_min_per_g: float
    sample_best_offset_arcsec: float  # the lowest calibration, as the seed's "experimental data directly"
    sample_k2_min_per_g: float

    def spline(self) -> CubicSpline:
        return CubicSpline(self.offsets_arcsec, self.k2_per_g)

    def to_json(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()}


def spline_minimum(offsets_arcsec: np.ndarray, k2_per_g: np.ndarray) -> tuple[float, float]:
    """(offset, K2) at the minimum of the cubic spline: a 0.001" grid, then a bounded line search (section 5.1)."""
    spline = CubicSpline(offsets_arcsec, k2_per_g)
    grid = np.arange(offsets_arcsec[0], offsets_arcsec[-1] + GRID_STEP_ARCSEC / 2, GRID_STEP_ARCSEC)
    i = int(np.argmin(spline(grid)))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    found = minimize_scalar(spline, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    return float(found.x), float(found.fun)


def fit_sweep(
    offsets_arcsec: Sequence[float], k2_per_g: Sequence[float], sigma_k2_per_g: Sequence[float], draws: int = MC_DRAWS
) -> SweepFit:
    """The sweep's spline minimum, with sigmas from `draws` redraws of each K2 within its own sigma."""
    x, y, s = (np.asarray(v, dtype=float) for v in (offsets_arcsec, k2_per_g, sigma_k2_per_g))
    order = np.argsort(x)
    x, y, s = x[order], y[order], s[order]
    if x.size < 4 or np.any(np.diff(x) <= 0):
        raise FitError(f"a cubic spline needs at least 4 distinct offsets, got {x.tolist()}")
    best, k2_min = spline_minimum(x, y)
    rng = np.random.default_rng(MC_SEED)
    minima = np.array([spline_minimum(x, y + s * rng.standard_normal(x.size)) for _ in range(draws)])
    lowest = int(np.argmin(y))
    return SweepFit(
        x,
        y,
        s,
        best,
        float(minima[:, 0].std(ddof=1)),
        k2_min,
        float(minima[:, 1].std(ddof=1)),
        float(x[lowest]),
        float(y[lowest]),
    )


@dataclass(frozen=True)
class Correction:
    """The inertia product left at the best offset and the mass that takes it away (seed 004 eqs. 21-22)."""

    k2_per_g: float
    inertia_product_kgm2: float
    sigma_inertia_product_kgm2: float
    mass_mg: float  # at each of four points
    sigma_mass_mg: float
    angular_momentum_kgm2ps: float
    radius_mm: float
    angle_deg: float


def correction(at_best: Calibration, angular_momentum_kgm2ps: float, radius_mm: float, angle_deg: float) -> Correction:
    """J_X2Z2 = kzz H / kz^2 (eq. 21, K2 calibrated at the best offset) and m = J / (2 b^2 sin 2 theta) (eq. 22)."""
    h = angular_momentum_kgm2ps
    j = float(ne.inertia_from_quadratic(at_best.kzz, at_best.kz, h))
    sigma_j = float(ne.inertia_from_quadratic(at_best.sigma_kzz, at_best.kz, h))
    b, theta = radius_mm * 1e-3, math.radians(angle_deg)
    mass_mg = float(ne.removed_mass_kg(j, b, theta)) * 1e6
    sigma_mg = float(ne.removed_mass_kg(sigma_j, b, theta)) * 1e6
    return Correction(at_best.k2_per_g, j, sigma_j, mass_mg, sigma_mg, h, radius_mm, angle_deg)


# ---- the session's analysis and report


@dataclass(frozen=True)
class Suppression:
    """Everything seed 004's method makes of one session."""

    calibrations: list[Calibration]
    sweep: SweepFit
    at_best: Calibration | None
    correction: Correction | None
    after: Calibration | None
    budget: Budget | None = None  # K2_at_best, removed_mass, K2_after_removal (procedures.nonlinear_suppression.budget)

    @property
    def k2_no_offset_per_g(self) -> float:
        """K2 with no offset: the sweep's calibration at 0" if there is one, else the spline there."""
        sweep = [c for c in self.calibrations if c.stage == SWEEP and c.offset_arcsec == 0.0]
        return sweep[0].k2_per_g if sweep else float(self.sweep.spline()(0.0))

    def gum(self) -> dict:
        """GUM fields of the headline figures: K2 at the best offset and after the removal, the removed mass
        (Type A; k from Student's t at the dof of the noise they rest on, pooled where pooled)."""
        rows: list[tuple[str, float, float, int, str]] = []
        for label, cal in (("K2_at_best", self.at_best), ("K2_after_removal", self.after)):
            if cal is not None:
                rows.append((label, cal.k2_per_g, cal.sigma_k2_per_g, cal.noise_dof or cal.dof, "1/g0"))
        if self.correction is not None and self.at_best is not None:
            c, cal = self.correction, self.at_best
            rows.append(("removed_mass", c.mass_mg, c.sigma_mass_mg, cal.noise_dof or cal.dof, "mg"))
        coefs: dict[str, dict] = {}
        if self.budget is not None:
            for name, value, sigma, _, _ in rows:
                coefs[name] = {"value": value, "sigma": sigma}
            return {"coefficients": coefs, **merged_json(coefs, self.budget, SEED004_TYPE_B)}
        for name, value, sigma, dof, unit in rows:
            type_a_json(coefs, (name,), np.array([value]), np.array([[sigma**2]]), dof, {name: unit}, "")
        return {"coefficients": coefs, "type_b": SEED004_TYPE_A_ONLY}

    def headline(self) -> dict[str, float | None]:
        k2_0 = self.k2_no_offset_per_g
        after = self.after.k2_per_g if self.after else None
        return {
            "k2_no_offset_per_g": k2_0,
            "best_offset_arcsec": self.sweep.best_offset_arcsec,
            "k2_spline_min_per_g": self.sweep.k2_min_per_g,
            "k2_at_best_per_g": self.at_best.k2_per_g if self.at_best else None,
            "removed_mass_mg": self.correction.mass_mg if self.correction else None,
            "k2_after_removal_per_g": after,
            "reduction": k2_0 / after if after else None,
        }


def correction_parameters(session: Session) -> tuple[float, float, float]:
    """H, r_f and theta of the mass removal as the session's procedure was given them."""
    p = session.meta.get("params", {})
    return (
        p.get("angular_momentum_kgm2ps", ne.ANGULAR_MOMENTUM_KGM2PS),
        p.get("end_radius_mm", ne.END_RADIUS_M * 1e3),
        p.get("removal_angle_deg", 45.0),
    )


def suppression(session: Session) -> Suppression:
    """The sweep fit, the correction at the best offset and the calibration after the mass removal (its Type B
    budget is added by procedures.nonlinear_suppression.budget.with_budget, which builds on this module)."""
    cals = calibrations(session)
    sweep = [c for c in cals if c.stage == SWEEP]
    fit = fit_sweep([c.offset_arcsec for c in sweep], [c.k2_per_g for c in sweep], [c.sigma_k2_per_g for c in sweep])
    at_best = next((c for c in cals if c.stage == AT_BEST), None)
    after = next((c for c in cals if c.stage == AFTER_REMOVAL), None)
    corr = correction(at_best, *correction_parameters(session)) if at_best else None
    return Suppression(cals, fit, at_best, corr, after)


SEED_FIGURES = {
    "k2_no_offset_per_g": ne.SEED004_K2_NO_OFFSET_PER_G,
    "best_offset_arcsec": ne.SEED004_BEST_OFFSET_ARCSEC,
    "k2_spline_min_per_g": ne.SEED004_K2_AT_BEST_PER_G,
    "k2_at_best_per_g": ne.SEED004_K2_AT_BEST_PER_G,
    "removed_mass_mg": ne.SEED004_REMOVED_MASS_KG * 1e6,
    "k2_after_removal_per_g": ne.SEED004_K2_AFTER_PER_G,
    "reduction": ne.SEED004_K2_NO_OFFSET_PER_G / ne.SEED004_K2_AFTER_PER_G,
}


def sweep_figure(s: Suppression):
    """K2 of every calibration against the digital offset, the spline and its minimum (seed 004 Fig. 10)."""
    fit = s.sweep
    fig, ax = plt.subplots(figsize=(7.5, 3.8))
    grid = np.linspace(fit.offsets_arcsec[0], fit.offsets_arcsec[-1], 2001)
    ax.errorbar(fit.offsets_arcsec, fit.k2_per_g, yerr=fit.sigma_k2_per_g, fmt="o", ms=4, label="calibrated K2")
    ax.plot(grid, fit.spline()(grid), lw=1, label="cubic spline")
    ax.errorbar(
        [fit.best_offset_arcsec],
        [fit.k2_min_per_g],
        xerr=[fit.sigma_best_offset_arcsec],
        fmt="v",
        ms=8,
        label=f'spline minimum {fit.best_offset_arcsec:+.3f}"',
    )
    for cal, marker in ((s.at_best, "s"), (s.after, "D")):
        if cal is not None:
            ax.errorbar(
                [cal.offset_arcsec],
                [cal.k2_per_g],
                yerr=[cal.sigma_k2_per_g],
                fmt=marker,
                ms=7,
                label=f"{cal.stage}: {cal.k2_per_g:.2e}/g0",
            )
    seed_x = [0.0, ne.SEED004_LOWEST_OFFSET_ARCSEC, ne.SEED004_BEST_OFFSET_ARCSEC]
    seed_y = [ne.SEED004_K2_NO_OFFSET_PER_G, ne.SEED004_K2_LOWEST_PER_G, ne.SEED004_K2_AT_BEST_PER_G]
    ax.plot(seed_x, seed_y, "x", color="k", label="seed 004 section 6")
    ax.set(
        yscale="log",
        xlabel="digital offset Δβ (arc-seconds)",
        ylabel="K2 = kzz / kz (1/g0)",
        title="Quadratic term against the angle servo's digital offset (seed 004 Fig. 10)",
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    fig.tight_layout()
    return fig


def report_html(s: Suppression, title: str) -> str:
    """The session's report: the sweep plot, the headline against the seed, the correction, every calibration."""
    ours = s.headline()
    head_rows = [(k, f"{SEED_FIGURES[k]:.4g}", "—" if v is None else f"{v:.4g}") for k, v in ours.items()]
    cal_rows = [
        (
            c.prefix,
            c.stage,
            f"{c.offset_arcsec:+.3f}",
            f"{c.kz:.6f}",
            f"{c.kzz:.4e}",
            f"{c.sigma_kzz:.1e}",
            f"{c.k2_per_g:.3e}",
            f"{c.sigma_k2_per_g:.1e}",
            c.n_points,
            f"{c.mu:.2f} / {c.mu_c:.2f}",
        )
        for c in s.calibrations
    ]
    fit = s.sweep
    parts = [
        "<h2>Offset sweep (seed 004 section 5.1)</h2>",
        svg(sweep_figure(s)),
        mapping_table(
            {
                "best offset, spline + line search (arcsec)": (
                    f"{fit.best_offset_arcsec:+.3f} ± {fit.sigma_best_offset_arcsec:.3f}"
                ),
                "K2 at the spline minimum (1/g0)": f"{fit.k2_min_per_g:.3e} ± {fit.sigma_k2_min_per_g:.1e}",
                "lowest calibration (arcsec, 1/g0)": (
                    f"{fit.sample_best_offset_arcsec:+.3f}, {fit.sample_k2_min_per_g:.3e}"
                ),
            }
        ),
        "<h2>Headline against seed 004 section 6</h2>",
        table(("figure", "seed 004", "this session"), head_rows),
    ]
    if s.correction:
        c = s.correction
        parts += [
            "<h2>Inertia-product correction (seed 004 eqs. 21-22)</h2>",
            mapping_table(
                {
                    "K2 calibrated at the best offset (1/g0)": f"{c.k2_per_g:.3e}",
                    "J_X2Z2 (kg m²), eq. 21": f"{c.inertia_product_kgm2:.4e} ± {c.sigma_inertia_product_kgm2:.1e}",
                    "mass to remove at each of 4 points (mg), eq. 22": f"{c.mass_mg:.1f} ± {c.sigma_mass_mg:.1f}",
                    "H (kg m²/s), b (mm), θ (deg)": f"{c.angular_momentum_kgm2ps:g}, {c.radius_mm:g}, {c.angle_deg:g}",
                }
            ),
        ]
    if s.budget is not None:
        parts += ["<h2>Uncertainty budget of the headline figures (GUM; contributions |c| u)</h2>",
                  table(*budget_rows(s.budget, with_sensitivity=True))]  # fmt: skip
    parts += [
        "<h2>Calibrations (integral precession, seed 000)</h2>",
        table(
            ("group", "stage", 'offset (")', "kz", "kzz (rad/s/g²)", "σ", "K2 (1/g0)", "σ", "points", "μ / μc"),
            cal_rows,
        ),
        f"<p>{esc(len(s.calibrations))} calibrations.</p>",
    ]
    return document(title, parts)


def summary(s: Suppression) -> str:
    h = s.headline()
    fit = s.sweep
    lines = [
        f"K2 with no offset {h['k2_no_offset_per_g']:.3e}/g0; best offset {fit.best_offset_arcsec:+.3f} "
        f"± {fit.sigma_best_offset_arcsec:.3f} arcsec (spline minimum {fit.k2_min_per_g:.3e}/g0)"
    ]
    if s.correction:
        c = s.correction
        lines.append(
            f"K2 at the best offset {c.k2_per_g:.3e}/g0: J_X2Z2 = {c.inertia_product_kgm2:.3e} kg m^2, "
            f"remove {c.mass_mg:.1f} ± {c.sigma_mass_mg:.1f} mg at each of 4 points"
        )
    if s.after:
        lines.append(
            f"K2 after the mass removal {s.after.k2_per_g:.3e} ± {s.after.sigma_k2_per_g:.1e}/g0: "
            f"reduced {h['reduction']:.1f} x (seed 004: {SEED_FIGURES['reduction']:.1f} x)"
        )
    return "\n".join(lines)


def servo_offset_measurement(key: str, prefix: str, stage: str, offset_arcsec: float, **extra) -> Measurement:
    """The record of a digital offset set before a calibration group (what `calibrations` reads)."""
    return Measurement(
        key, SERVO_OFFSET_KIND, {"prefix": prefix, "stage": stage, "offset_arcsec": offset_arcsec, **extra}
    )
