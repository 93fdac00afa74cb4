"""GUM budget of seed 004's headline figures: K2 = kzz / kz at the best offset and after the mass removal, and the
mass to remove (seed 004 eqs. 21-22; JCGM 100).

Each calibration is a seed-000 integral precession identification, so its (kz, kzz) budget is seed 000's
(methods.seed000.budget: Zs1, axs1, eps_f, A0, g, read-head latency, latitude, second harmonic, each propagated
by refit), with the fit's Type A row taken at the rate noise pooled over the calibrations that share it (the
sigma the method quotes, with its pooled dof). K2 and the mass follow by the chain rule (GUM 5.1.2;
methods.common.uncertainty.transformed); the mass adds the inputs of eqs. 21-22 that the calibration does not
see: the gyro's angular momentum H, the removal radius b and angle theta, each by re-running `correction` at
x +- u. Both calibrations see the same station, so their shared Type B rows stay correlated (`stacked`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from methods.common.references import Reference, default_references, reference_input
from methods.common.uncertainty import Budget, refit_sources, stacked, transformed, with_fit
from methods.seed000.budget import seed000_budget
from methods.seed000.identify import identify
from methods.seed004.analysis import Calibration, Suppression, correction, correction_parameters
from station.session import PointRecord, Session, StationInfo


def _pooled_budget(
    station: StationInfo,
    points: Sequence[PointRecord],
    cal: Calibration,
    refs: Mapping[str, Reference],
    timer_rows: bool,
) -> tuple[Budget, float, float, int, int]:
    """Seed 000's budget of one calibration, its fit at the pooled rate noise; kz, kzz and their places."""
    session = Session(station, list(points))
    result = identify(session)
    full = seed000_budget(session, result, {}, refs, timer_rows=timer_rows)
    unit_cov = result.cov / result.sigma_residual**2
    dof = cal.noise_dof or cal.dof
    full = with_fit(full, unit_cov * cal.noise_radps**2, dof, f"rate noise pooled over {dof} dof (seed 000 eq. 21)")
    i, j = result.names.index("kz"), result.names.index("kzz")
    return full, float(result.values[i]), float(result.values[j]), i, j


def calibration_budget(
    station: StationInfo,
    points: Sequence[PointRecord],
    cal: Calibration,
    name: str,
    references: Mapping[str, Reference] | None = None,
    *,
    timer_rows: bool = True,
) -> Budget:
    """The budget of K2 = kzz / kz of one calibration (named `name`), its fit at the pooled rate noise."""
    refs = references if references is not None else default_references()
    full, kz, kzz, i, j = _pooled_budget(station, points, cal, refs, timer_rows)
    jac = np.zeros((1, len(full.names)))
    jac[0, i], jac[0, j] = -kzz / kz**2, 1.0 / kz
    return transformed(full, (name,), np.array([kzz / kz]), jac, {name: "1/g0"})


def correction_budget(
    station: StationInfo,
    points: Sequence[PointRecord],
    cal: Calibration,
    angular_momentum_kgm2ps: float,
    radius_mm: float,
    angle_deg: float,
    references: Mapping[str, Reference] | None = None,
    *,
    timer_rows: bool = True,
) -> Budget:
    """The budget of (K2_at_best, removed_mass) from the calibration at the best offset (eqs. 21-22)."""
    refs = references if references is not None else default_references()
    full, kz, kzz, i, j = _pooled_budget(station, points, cal, refs, timer_rows)
    mass = correction(cal, angular_momentum_kgm2ps, radius_mm, angle_deg).mass_mg
    jac = np.zeros((2, len(full.names)))
    jac[0, i], jac[0, j] = -kzz / kz**2, 1.0 / kz  # K2 = kzz / kz
    jac[1, i], jac[1, j] = -2.0 * mass / kz, mass / kzz  # m = kzz H / kz^2 / (2 b^2 sin 2 theta), eqs. 21-22
    both = transformed(full, ("K2_at_best", "removed_mass"), np.array([kzz / kz, mass]), jac,
                       {"K2_at_best": "1/g0", "removed_mass": "mg"})  # fmt: skip
    inputs = []
    for key, name, label, unit in (
        ("H", "angular_momentum_kgm2ps", "angular momentum H of the gyro (eq. 21)", "kg m^2/s"),
        ("b", "end_radius_mm", "radius b of the removal points (eq. 22)", "mm"),
        ("theta", "removal_angle_deg", "angle theta of the removal points (eq. 22)", "deg"),
    ):
        r = refs[name]
        value = {"H": angular_momentum_kgm2ps, "b": radius_mm, "theta": angle_deg}[key]
        note = r.distribution + ("; d m / d theta = 0 at 45 deg (second order only)" if key == "theta" else "")
        inputs.append(reference_input(key, label, value, r, unit=unit, note=note))

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
    parts = []
    if at_best is not None:
        parts.append(correction_budget(station, *at_best, *correction_inputs, references, timer_rows=timer_rows))
    if after is not None:
        parts.append(calibration_budget(station, *after, "K2_after_removal", references, timer_rows=timer_rows))
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else stacked(parts[0], parts[1])


def with_budget(session: Session, s: Suppression) -> Suppression:
    """The suppression with its Type B budget: each calibration by the points of its own prefix."""

    def with_points(cal: Calibration | None) -> tuple[list[PointRecord], Calibration] | None:
        return None if cal is None else ([p for p in session.points if p.point_id.startswith(cal.prefix + "-")], cal)

    budget = suppression_budget(session.station, with_points(s.at_best), with_points(s.after),
                                correction_parameters(session))  # fmt: skip
    return replace(s, budget=budget)
