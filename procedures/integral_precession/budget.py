"""GUM uncertainty budget of the seed-000 coefficients (JCGM 100; seed 000 eqs. 19-22, 31-34).

Type A: the weighted joint fit (eq. 22, its n - p dof). Type B, each propagated through
the identification itself (the refit at x +- u, procedures.common.uncertainty.sensitivity):

- Zs1 = z0 + z1 w (eq. 32) and axs1 (eq. 34), measured (the session's params state them): the compensation is
  re-run with the perturbed value; z0 and z1 are correlated through their line fit (their covariance enters
  once, as a block). Not measured (issue 32, d2): budgeted at what seed 000 found on its table, of either sign
  (Zs1 with the shape of eq. 32, +71 um at 10 Hz; axs1 -0.92 arcsec), never at the accuracy of the instrument
  that would have measured them;
- eps_f (w = w_cmd (1 + eps_f)), A0 and g (a = A0 w^2 / g), read-head latency (t1, t2):
  the design is rebuilt with the perturbed value;
- latitude: an input the identification does not model; its rate change per point is computed by the exact
  window model of the twin (station.twin.precession: the rate's Fourier series over a crank turn, integrated
  over [0, Tm] with psi = w (t - t1)) at the identified coefficients, and refitted;
- the second harmonic (Zs2, Zc2), the same way, listed and not added (SECOND_HARMONIC_NOT_ADDED);
- timer resolution: a random error of each stamp (Tm, t1, t2 of every point), propagated
  point by point and root-sum-squared; it is already in the fit's scatter (Type A), so it is
  listed and not added again (GUM 4.3.10 double counting).

`table_error_rows` says on the certificate which table errors were compensated, which not and why.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from procedures.common.references import Reference, default_references
from procedures.common.uncertainty import (
    Budget,
    Shape,
    Source,
    UncertaintyError,
    check_uncertainty,
    type_a_source,
    type_b_source,
)
from procedures.integral_precession.identify import (
    COEFFICIENT_UNITS,
    Compensation,
    Identification,
    Method,
    design,
    identify,
)
from procedures.integral_precession.parasitic_rotation import SEED_HARMONICS_ARCSEC
from procedures.integral_precession.table_motion import SEED_Z0_M, SEED_Z1_M_S_PER_RAD
from station.least_squares import fit_joint
from station.session import PointRecord, Session
from station.twin.config import InstrumentCoefficients, TwinConfig
from station.twin.nonlinear_error import ARCSEC_RAD
from station.twin.precession import PrecessionWindow, periodic_rate

# The references every seed-000 budget uses (config/instruments/references.toml); the error-source experiments'
# references join them on the certificate's traceability only when the session measured that error
# (`traceability_keys`).
SEED000_REFERENCES = ("A0_m", "g_mps2", "latitude_deg", "timer_resolution_s", "readhead_latency_s")
EXPERIMENT_REFERENCES = {"zs1": ("zs1_z0_m", "zs1_z1_m_s"), "axs1": ("axs1_rad",), "eps_f": ("eps_f",)}

# The table errors seed 000 measured on its table (6.1): the budget of one a session did not measure.
SEED000_ZS1_LINE_M = (SEED_Z0_M, SEED_Z1_M_S_PER_RAD)  # Zs1(w) = z0 + z1 w: eq. 32, the line through Table 5
SEED000_AXS1_RAD = SEED_HARMONICS_ARCSEC["x"][0] * ARCSEC_RAD  # eq. 34 on Table 7's gradiometer readings
ZS1_STATED_AT_HZ = 10.0  # an unmeasured Zs1 is stated at the table's top frequency (its largest on seed 000's line)

SECOND_HARMONIC_NOT_ADDED = (
    "listed, not added: seed 000 finds Zs2 and Zc2 at the grating's sampling-delay limit (Table 5, eq. 31) and "
    "judges them without effect on the calibration (6.1.1), and physics.md's nominal motion has none; read as real, "
    "Table 5's Zc2 of 47.5 um at 9 Hz would need a row of its own: the parasitic translation experiment measures it"
)


def seed000_zs1_m(w_radps: float) -> float:
    """Seed 000's Zs1 at w (eq. 32): +31, +51, +71 um at 8, 9, 10 Hz (Table 5 measured +50 and +83 um at 9, 10)."""
    z0, z1 = SEED000_ZS1_LINE_M
    return z0 + z1 * w_radps


@dataclass(frozen=True)
class Measured:
    """An input of the budget: its value, standard uncertainty and how it was obtained.

    `measured`: the session's params state it (an error-source experiment was run); `compensated`: the
    identification corrected it. An input neither measured nor compensated is budgeted at seed 000's magnitude."""

    value: float
    u: float
    origin: str
    shape: Shape = "normal"  # the references' shape where u comes from them; a measured sigma: normal
    measured: bool = True
    compensated: bool = False


# The params that state each table error measured: its values (other than 0) and its sigmas (any value).
MEASURED_BY = {
    "zs1": (("zs1_z0_m", "zs1_z1_m_s"), ("zs1_z0_sigma_m", "zs1_z1_sigma_m_s")),
    "axs1": (("axs1_rad",), ("axs1_sigma_rad",)),
    "eps_f": (("eps_f",), ("eps_f_sigma",)),
}


def found_none_params(references: Mapping[str, Reference] | None = None) -> dict[str, float]:
    """The params of a session whose error-source experiments were run and found no table error, each at its
    measuring instrument's accuracy (the references): what a test or benchmark on sessions made without table
    errors states, so that its budget is the measured one."""
    refs = references if references is not None else default_references()
    values = [k for vals, _ in MEASURED_BY.values() for k in vals]
    sigmas = [sig for vals, sigs in MEASURED_BY.values() for sig in sigs]
    return {k: 0.0 for k in values} | {sig: refs[k].standard_uncertainty for k, sig in zip(values, sigmas, strict=True)}


def is_measured(params: Mapping) -> dict[str, bool]:
    """Which table errors (zs1, axs1, eps_f) the session's params state as measured."""
    return {e: any(float(params.get(k) or 0.0) != 0.0 for k in values) or any(params.get(k) is not None for k in sigmas)
            for e, (values, sigmas) in MEASURED_BY.items()}  # fmt: skip


def traceability_keys(params: Mapping) -> tuple[str, ...]:
    """The references of a seed-000 certificate's traceability: the station's, and an experiment's only when the
    session measured its error (issue 32: never cite an experiment that was not run)."""
    measured = is_measured(params)
    return SEED000_REFERENCES + tuple(k for e, keys in EXPERIMENT_REFERENCES.items() if measured[e] for k in keys)


def measured_inputs(params: Mapping, refs: Mapping[str, Reference], compensated: bool = True) -> dict[str, Measured]:
    """z0, z1, axs1, eps_f as the budget takes them (issue 32, d2).

    Measured (the params state it): u is the params' sigma, else the references' (the measuring instrument's
    accuracy); an identification that did not compensate it (`compensated` False) takes the value 0 and folds a
    measured v into its uncertainty, u = sqrt(u^2 + v^2). Not measured: value 0, budgeted at what seed 000 found
    on its table, one standard uncertainty its size there: axs1 0.92 arcsec (eq. 34), Zs1 by `zs1_unmeasured`
    (eq. 32), eps_f at Table 6's (the references' default).
    """
    measured = is_measured(params)

    def one(key: str, sigma_key: str, group: str) -> Measured:
        v = float(params.get(key, 0.0) or 0.0)
        s = params.get(sigma_key)
        u = float(s) if s is not None else refs[key].standard_uncertainty
        origin = f"u from params {sigma_key}" if s is not None else f"u from the references ({refs[key].distribution})"
        if not measured[group]:
            if group == "axs1":
                size = abs(SEED000_AXS1_RAD)
                return Measured(
                    0.0,
                    size,
                    f"not compensated (not measured): normal, u = {size / ARCSEC_RAD:.2f} "
                    "arcsec, the size of the axs1 seed 000 measured (eq. 34, Table 7)",
                    measured=False,
                )
            return Measured(0.0, u, "not compensated (not measured): " + origin, refs[key].shape, measured=False)
        if not compensated and v:
            return Measured(0.0, math.hypot(u, v), f"measured {v:.3g}, not compensated here: u = sqrt(u^2 + v^2); "
                            + origin)  # fmt: skip
        shape = refs[key].shape if s is None else "normal"
        status = "compensated; " if v and compensated else "measured 0, nothing to compensate; " if not v else ""
        return Measured(v, u, status + origin, shape, compensated=bool(v and compensated))

    out = {
        "zs1_z0_m": one("zs1_z0_m", "zs1_z0_sigma_m", "zs1"),
        "zs1_z1_m_s": one("zs1_z1_m_s", "zs1_z1_sigma_m_s", "zs1"),
        "axs1_rad": one("axs1_rad", "axs1_sigma_rad", "axs1"),
        "eps_f": one("eps_f", "eps_f_sigma", "eps_f"),
    }
    for k, m in out.items():
        check_uncertainty(k, m.value, m.u)
    return out


def _comp(m: Mapping[str, float], base: Compensation) -> Compensation:
    z0, z1 = m["zs1_z0_m"], m["zs1_z1_m_s"]
    zs1 = (lambda w: z0 + z1 * w) if (z0 or z1) else None
    return replace(base, zs1_m=zs1, axs1_rad=m["axs1_rad"], eps_f=m["eps_f"])


class _Refit:
    """The identification at perturbed inputs: same session, weights and method, design rebuilt."""

    def __init__(self, session: Session, result: Identification, values: Mapping[str, float]) -> None:
        self.session, self.method = session, result.method
        self.values = dict(values)
        self.weights = result.weights
        self.rates, self.index, _, self.names, self.vib = design(session, result.method, self.compensation())

    def compensation(self, **changes: float) -> Compensation:
        v = {**self.values, **changes}
        base = Compensation(latency_s=v["latency_s"], A0_m=v["A0_m"], g_mps2=v["g_mps2"])
        return _comp(v, base)

    def __call__(self, delta_rates: np.ndarray | None = None, session: Session | None = None, **changes) -> np.ndarray:
        s = session or self.session
        rates, index, L, names, _ = design(s, self.method, self.compensation(**changes))
        if session is None:
            rates = self.rates
        if delta_rates is not None:
            rates = rates + delta_rates
        return fit_joint(rates, index, L, names, weights=self.weights).values

    def along(self, key: str):
        return lambda x: self(**{key: x})


def _exact_cfg(session: Session, result: Identification, **station_changes) -> TwinConfig:
    st = session.station
    k = dict(zip(result.names, result.values, strict=True))
    geo = replace(st, **station_changes)
    coefs = InstrumentCoefficients(k0=0.0, kz=k.get("kz", 0.56), kzz=k["kzz"], ky=k["ky"], k3=k["k3"])
    return TwinConfig(station=geo, instrument=coefs)


def _window_mean_rate(p: PointRecord, cfg: TwinConfig) -> float:
    """Exact mean rate over [0, Tm] of the twin's rate model, psi = w (t - t1) (physics.md, window means)."""
    theta = math.radians(p.position_deg)
    rate = periodic_rate(theta, p.freq_hz, cfg)
    w = 2 * math.pi * p.freq_hz
    gamma0 = -w * (p.t1_s or 0.0)
    return float(PrecessionWindow(rate, w, gamma0).phi_rad(p.Tm_s)) / p.Tm_s


def exact_rate_shift(session: Session, cfg_with: TwinConfig, cfg_without: TwinConfig) -> np.ndarray:
    """Change of every point's window-mean rate when an unmodelled effect is switched on."""
    return np.array([_window_mean_rate(p, cfg_with) - _window_mean_rate(p, cfg_without) for p in session.points])


def _shifted(session: Session, i: int, field_name: str, du: float) -> Session:
    pts = list(session.points)
    p = pts[i]
    pts[i] = replace(p, **{field_name: getattr(p, field_name) + du})
    return replace(session, points=pts)


def timer_resolution_contribution(session: Session, refit: _Refit, u_s: float) -> np.ndarray:
    """RSS over every stamp (Tm of each point, t1 and t2 of each vibration point) of |dK/dt| u (GUM eq. 10)."""
    base = refit(session=session)
    total = np.zeros_like(base)
    for i, p in enumerate(session.points):
        for name in ("Tm_s", "t1_s", "t2_s") if p.kind == "vibration" else ("Tm_s",):
            d = refit(session=_shifted(session, i, name, u_s)) - base
            total += d * d
    return np.sqrt(total)


def zs1_unmeasured_note() -> str:
    """How an unmeasured Zs1 is budgeted, in words (its budget row's note and the certificate's table)."""
    size_um = abs(seed000_zs1_m(2 * math.pi * ZS1_STATED_AT_HZ)) * 1e6
    return (f"not compensated (not measured): Zs1(w) with the shape seed 000 measured (eq. 32, Table 5), normal, "
            f"u = its size there: {size_um:.0f} um at {ZS1_STATED_AT_HZ:g} Hz, "
            f"{seed000_zs1_m(2 * math.pi * 8.0) * 1e6:.0f} um at 8 Hz")  # fmt: skip


def zs1_unmeasured(refit: _Refit) -> Source:
    """The row of a Zs1 the session did not measure: Zs1(w) with the shape of seed 000's line (eq. 32), one standard
    uncertainty its size there (a table like seed 000's has it, of a sign not known), stated at ZS1_STATED_AT_HZ
    (71 um at 10 Hz)."""
    at_ref = seed000_zs1_m(2 * math.pi * ZS1_STATED_AT_HZ)
    z0, z1 = (c / at_ref for c in SEED000_ZS1_LINE_M)
    return type_b_source(f"parasitic translation Zs1 at {ZS1_STATED_AT_HZ:g} Hz, not measured (eq. 32)", 0.0,
                         abs(at_ref), "m", lambda x: refit(zs1_z0_m=x * z0, zs1_z1_m_s=x * z1),
                         note=zs1_unmeasured_note())  # fmt: skip


def seed000_budget(
    session: Session,
    result: Identification,
    params: Mapping | None = None,
    references: Mapping[str, Reference] | None = None,
    *,
    compensated: bool = True,
    timer_rows: bool = True,
) -> Budget:
    """The GUM budget of `result` (an integral or baseline identification of `session`); `compensated`: whether
    `result` used the params' measured Zs1, axs1 and eps_f; `timer_rows` False leaves the timer-resolution
    row (listed, not added) at zero."""
    params = dict(params if params is not None else session.meta.get("params", {}))
    refs = dict(references if references is not None else default_references())
    meas = measured_inputs(params, refs, compensated)
    st = session.station
    values = {k: m.value for k, m in meas.items()} | {"latency_s": 0.0, "A0_m": st.A0_m, "g_mps2": st.g_mps2}
    refit = _Refit(session, result, values)
    names = result.names
    sources: list[Source] = [type_a_source(names, result.cov, result.dof, f"weights: {result.weighting}")]
    labels = {
        "zs1_z0_m": "parasitic translation Zs1: z0 (eq. 32)",
        "zs1_z1_m_s": "parasitic translation Zs1: z1 (eq. 32)",
        "axs1_rad": "parasitic rotation axs1 (gradiometer, eq. 34)",
        "eps_f": "vibration frequency error eps_f (Table 6)",
    }
    zs1_measured = meas["zs1_z0_m"].measured
    if not zs1_measured:
        labels.pop("zs1_z0_m"), labels.pop("zs1_z1_m_s")
        sources.append(zs1_unmeasured(refit))
    for key, label in labels.items():
        m = meas[key]
        sources.append(type_b_source(label, m.value, m.u, refs[key].unit, refit.along(key), note=m.origin,
                                     shape=m.shape))  # fmt: skip
    corr = float(params.get("zs1_z0_z1_corr", 0.0) or 0.0)
    if not -1.0 <= corr <= 1.0:
        raise UncertaintyError(f"params zs1_z0_z1_corr = {corr!r}: expected a correlation in [-1, 1]")
    for key, label, value in (
        ("A0_m", "crank radius A0", st.A0_m),
        ("g_mps2", "local gravity g", st.g_mps2),
        ("readhead_latency_s", "read-head latency (t1, t2 stamped late)", 0.0),
    ):
        r = refs[key]
        along = "latency_s" if key == "readhead_latency_s" else key
        note = f"{r.distribution}; not corrected" if key == "readhead_latency_s" else r.distribution
        sources.append(type_b_source(label, value, r.standard_uncertainty, r.unit, refit.along(along), note=note,
                                     shape=r.shape))  # fmt: skip
    # inputs outside the identification model: exact rate change -> refit
    cfg0 = _exact_cfg(session, result)
    r_lat = refs["latitude_deg"]
    lat_note = f"{r_lat.distribution}; enters the static and vibration rates alike through w_ie sin(lam - theta)"

    def lat_refit(x: float) -> np.ndarray:
        return refit(delta_rates=exact_rate_shift(session, _exact_cfg(session, result, latitude_deg=x), cfg0))

    sources.append(type_b_source("latitude", st.latitude_deg, r_lat.standard_uncertainty, "deg", lat_refit,
                                 note=lat_note, shape=r_lat.shape))  # fmt: skip
    r2 = refs["second_harmonic_m"]
    for comp_key in ("Zs2", "Zc2"):

        def harm_refit(x: float, comp_key: str = comp_key) -> np.ndarray:
            cfg = cfg0.with_effect("waveform_harmonics", **{comp_key: x})
            return refit(delta_rates=exact_rate_shift(session, cfg, cfg0))

        sources.append(type_b_source(f"unmodelled second harmonic {comp_key}", 0.0, r2.standard_uncertainty, "m",
                                     harm_refit, note=f"{r2.distribution}; {SECOND_HARMONIC_NOT_ADDED}",
                                     shape=r2.shape, in_combined=False))  # fmt: skip
    r_t = refs["timer_resolution_s"]
    # listed only (in the Type A scatter): `timer_rows=False` skips its 3 refits per point (Monte Carlo)
    c_t = np.zeros(len(names))
    if timer_rows:
        c_t = timer_resolution_contribution(session, refit, r_t.standard_uncertainty)
    sources.append(
        Source(
            "timer resolution (every stamp)",
            "B",
            0.0,
            r_t.standard_uncertainty,
            "s",
            c_t / r_t.standard_uncertainty if r_t.standard_uncertainty else c_t,
            note=f"{r_t.distribution}; "
            "random per stamp, root-sum-square over all stamps: already in the fit's scatter (Type A), not added",
            in_combined=False,
            shape=r_t.shape,
        )
    )
    extra = np.zeros((len(names), len(names)))
    if zs1_measured:
        by_name = {s.source: s for s in sources}
        c0 = by_name[labels["zs1_z0_m"]].sensitivity * meas["zs1_z0_m"].u
        c1 = by_name[labels["zs1_z1_m_s"]].sensitivity * meas["zs1_z1_m_s"].u
        extra = corr * (np.outer(c0, c1) + np.outer(c1, c0))
    units = {n: COEFFICIENT_UNITS[n] for n in names}
    return Budget(names, np.asarray(result.values, dtype=float), units, sources, cov_a=result.cov, extra_cov=extra)


def identify_with_budget(
    session: Session, method: Method = "integral", compensation: Compensation | None = None
) -> Identification:
    """`identify` and its GUM budget (seed000_budget with the session's params and the shipped references): the one
    path of the procedure's analysis and of `station identify`; `compensation` given: the measured Zs1, axs1 and
    eps_f of the params were compensated."""
    result = identify(session, method, compensation)
    result.budget = seed000_budget(session, result, compensated=compensation is not None)
    return result


TABLE_ERRORS = (  # the table errors of seed 000 6.1: quantity, its inputs, the procedure that measures it
    ("parasitic translation Zs1 (eq. 32)", ("zs1_z0_m", "zs1_z1_m_s"), "integral_precession.parasitic_translation"),
    ("parasitic rotation axs1 (eq. 34)", ("axs1_rad",), "integral_precession.parasitic_rotation"),
    ("vibration frequency error eps_f (Table 6)", ("eps_f",), "integral_precession.frequency_stability"),
)
TABLE_ERRORS_HEADER = ("table error (seed 000 6.1)", "compensated", "why, and how it is budgeted")


def table_error_rows(params: Mapping, compensated: bool,
                     references: Mapping[str, Reference] | None = None) -> list[tuple[str, str, str]]:  # fmt: skip
    """Which table errors the identification compensated, which not and why (the certificate's table)."""
    meas = measured_inputs(params, dict(references if references is not None else default_references()), compensated)
    rows = []
    for quantity, keys, experiment in TABLE_ERRORS:
        m = [meas[k] for k in keys]
        values = ", ".join(f"{k} = {float(params.get(k) or 0.0):.3g}" for k in keys)
        if not m[0].measured:
            how = zs1_unmeasured_note() if keys[0] == "zs1_z0_m" else m[0].origin
            rows.append((quantity, "no (not measured)", f"{experiment} was not run; budgeted at seed 000's magnitude: "
                         + how.removeprefix("not compensated (not measured): ")))  # fmt: skip
        elif any(x.compensated for x in m):
            rows.append((quantity, "yes", f"measured {values}; u at the measurement's uncertainty"))
        elif all(float(params.get(k) or 0.0) == 0.0 for k in keys):
            rows.append((quantity, "nothing to compensate", f"measured {values}; u at the measurement's uncertainty"))
        else:
            rows.append((quantity, "no (measured, not applied)", f"measured {values}, not applied by this "
                         "identification: the value is folded into u"))  # fmt: skip
    rows.append(("second harmonic Zs2, Zc2 (Table 5)", "no (not modelled)", SECOND_HARMONIC_NOT_ADDED))
    return rows
