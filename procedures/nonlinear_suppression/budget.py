"""GUM budget of seed 004's headline figures: K2 = kzz / kz at the best offset and after the mass removal, and the
mass to remove (seed 004 eqs. 21-22; JCGM 100).

Each calibration is a seed-000 integral precession identification, so its (kz, kzz) budget is seed 000's
(procedures.integral_precession.budget: Zs1, axs1, eps_f, A0, g, read-head latency, latitude, second harmonic, each
propagated
by refit), with the fit's Type A row taken at the rate noise pooled over the calibrations that share it (the
sigma the method quotes, with its pooled dof). K2 and the mass follow by the chain rule (GUM 5.1.2;
procedures.common.uncertainty.transformed); the mass adds the inputs of eqs. 21-22 that the calibration does not
see: the gyro's angular momentum H, the removal radius b and angle theta, each by re-running `correction` at
x +- u. Both calibrations see the same station, so their shared Type B rows stay correlated (`stacked`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from procedures.common.references import Reference, default_references, reference_input
from procedures.common.uncertainty import Budget, refit_sources, stacked, transformed, with_fit
from procedures.integral_precession.budget import seed000_budget
from procedures.integral_precession.identify import identify
from procedures.nonlinear_suppression.analysis import Calibration, Suppression, correction, correction_parameters
from station.session import PointRecord, Session, StationInfo

Output = Callable[[float, float], tuple[str, str, float, float, float]]  # (kz, kzz) -> name, unit, y, dy/dkz, dy/dkzz


def k2_output(name: str) -> Output:
    """K2 = kzz / kz, in 1/g0."""
    return lambda kz, kzz: (name, "1/g0", kzz / kz, -kzz / kz**2, 1.0 / kz)


def _chained(
    station: StationInfo,
    points: Sequence[PointRecord],
    cal: Calibration,
    refs: Mapping[str, Reference],
    timer_rows: bool,
    outputs: Sequence[Output],
) -> Budget:
    """Seed 000's budget of one calibration, its fit at the pooled rate noise, carried by the chain rule to each
    output y(kz, kzz) (GUM 5.1.2)."""
    session = Session(station, list(points))
    result = identify(session)
    full = seed000_budget(session, result, {}, refs, timer_rows=timer_rows)
    unit_cov = result.cov / result.sigma_residual**2
    dof = cal.noise_dof or cal.dof
    full = with_fit(full, unit_cov * cal.noise_radps**2, dof, f"rate noise pooled over {dof} dof (seed 000 eq. 21)")
    i, j = result.names.index("kz"), result.names.index("kzz")
    rows = [out(float(result.values[i]), float(result.values[j])) for out in outputs]
    jac = np.zeros((len(rows), len(full.names)))
    for r, (_, _, _, d_kz, d_kzz) in enumerate(rows):
        jac[r, i], jac[r, j] = d_kz, d_kzz
    return transformed(full, tuple(r[0] for r in rows), np.array([r[2] for r in rows]), jac,
                       {r[0]: r[1] for r in rows})  # fmt: skip


def correction_budget(
    station: StationInfo,
    points: Sequence[PointRecord],
    cal: Calibration,
    correction_inputs: tuple[float, float, float],
    refs: Mapping[str, Reference],
    timer_rows: bool,
) -> Budget:
    """The budget of (K2_at_best, removed_mass) from the calibration at the best offset (eqs. 21-22); the
    correction's inputs H, b and theta as given."""
    angular_momentum_kgm2ps, radius_mm, angle_deg = correction_inputs
    mass = correction(cal, angular_momentum_kgm2ps, radius_mm, angle_deg).mass_mg

    def mass_output(kz: float, kzz: float) -> tuple[str, str, float, float, float]:
        """m = kzz H / kz^2 / (2 b^2 sin 2 theta) (eqs. 21-22)."""
        return "removed_mass", "mg", mass, -2.0 * mass / kz, mass / kzz

    both = _chained(station, points, cal, refs, timer_rows, [k2_output("K2_at_best"), mass_output])
    inputs = []
    for key, name, label, value in (
        ("H", "angular_momentum_kgm2ps", "angular momentum H of the gyro (eq. 21)", angular_momentum_kgm2ps),
        ("b", "end_radius_mm", "radius b of the removal points (eq. 22)", radius_mm),
        ("theta", "removal_angle_deg", "angle theta of the removal points (eq. 22)", angle_deg),
    ):
        r = refs[name]
        note = r.distribution + ("; d m / d theta = 0 at 45 deg (second order only)" if key == "theta" else "")
        inputs.append(reference_input(key, label, value, r, note=note))

    def refit(x: Mapping[str, float]) -> np.ndarray:
        """K2 and the mass with eqs. 21-22 re-run at H, b, theta = x."""
        return np.array([cal.k2_per_g, correction(cal, x["H"], x["b"], x["theta"]).mass_mg])

    return replace(both, sources=[*both.sources, *refit_sources(inputs, refit)])


def suppression_budget(
    station: StationInfo,
    at_best: tuple[Sequence[PointRecord], Calibration] | None,
    after: tuple[Sequence[PointRecord], Calibration] | None,
    correction_inputs: tuple[float, float, float],
    references: Mapping[str, Reference] | None = None,
    *,
    timer_rows: bool = True,
) -> Budget | None:
    """The session's budget of K2_at_best, removed_mass and K2_after_removal (those the session has)."""
    refs = references if references is not None else default_references()
    parts = []
    if at_best is not None:
        parts.append(correction_budget(station, *at_best, correction_inputs, refs, timer_rows))
    if after is not None:
        parts.append(_chained(station, *after, refs, timer_rows, [k2_output("K2_after_removal")]))
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else stacked(parts[0], parts[1])


def calibration_points(session: Session, cal: Calibration) -> list[PointRecord]:
    """The points of one calibration: those of its group prefix."""
    return [p for p in session.points if p.point_id.startswith(cal.prefix + "-")]


def with_budget(session: Session, s: Suppression) -> Suppression:
    """The suppression with its Type B budget: each calibration by the points of its own prefix."""

    def with_points(cal: Calibration | None) -> tuple[list[PointRecord], Calibration] | None:
        return None if cal is None else (calibration_points(session, cal), cal)

    budget = suppression_budget(session.station, with_points(s.at_best), with_points(s.after),
                                correction_parameters(session))  # fmt: skip
    return replace(s, budget=budget)
