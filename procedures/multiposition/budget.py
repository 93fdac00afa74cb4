"""GUM budget of seed 003's calibration of PIGA A, without and with the angle-error compensation (JCGM 100;
seed 003 eqs. 15, 43-49).

Without compensation (Tables 3-4) the static fit (eq. 49's Type A) takes the head's angles as exact; its Type B
rows, each by re-running the fit at the angles it would have used had it known the input at x +- u:

- each angle-error harmonic ck, sk (eq. 15), not compensated: value 0, u from the head's stated accuracy
  (config/instruments/references.toml index_harmonic_rad); the angles become theta + dtheta(theta);
- the head zero of the self-alignment (its own sigma, eq. 56), which turns every angle;
- the latitude, through the earth rate w_ie sin(lam - theta) that the fit removes.

With compensation (Table 7) the harmonics and the mounting offset are fitted by the four-pose method: their
covariance, carried through the compensated angles, is one block row with the four-pose fit's dof (the
compensated_total of procedures.multiposition.gravity_field); the latitude is re-run through both fits.

Both list the counter/timer's resolution (two stamps a window, rate w / Tm each): already in the fit's scatter
(Type A), not added (GUM 4.3.10). Local g is the unit of the inputs (c = cos theta in g) and does not enter.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from procedures.common.references import Reference, default_references, reference_input
from procedures.common.uncertainty import Budget, Input, Source, fit_budget, refit_sources
from procedures.multiposition.four_pose import (
    FourPoseFit,
    PoseWindow,
    angle_error_rad,
    fit_four_pose,
    harmonic_basis,
    harmonic_names,
)
from procedures.multiposition.lsq import UNITS, Fit
from procedures.multiposition.static_model import fit_static, rate_slope_radps, regressors
from station.session import StationInfo

TYPE_B = {
    "uncompensated": "Type B by refit (procedures.multiposition.budget): the angle-error harmonics "
    "(not compensated), the head zero, the latitude; the timer resolution listed (in the scatter)",
    "compensated_total": "Type B by refit (procedures.multiposition.budget): the four-pose harmonics and offset "
    "(a Type A block with its dof), the latitude through both fits; the timer resolution listed (in the scatter)",
}


def _units(names: tuple[str, ...]) -> dict[str, str]:
    return {n: UNITS.get(n, "") for n in names}


def timer_row(fit: Fit, angles_rad: np.ndarray, rates_radps: np.ndarray, Tm_s: np.ndarray, timer: Reference) -> Source:
    """The timer resolution, listed: each window's rate w / Tm moves by w u sqrt(2) / Tm (two stamps), through
    the linear fit K = pinv(X) y, root-sum-square over the windows; the reference's distribution in both columns."""
    u_s = timer.standard_uncertainty
    X = regressors(np.cos(angles_rad), fit.names)
    du = np.abs(rates_radps) * math.sqrt(2.0) * u_s / np.asarray(Tm_s, dtype=float)
    contribution = np.sqrt(((np.linalg.pinv(X) * du) ** 2).sum(axis=1))
    return Source("timer resolution (two stamps a window)", "B", 0.0, u_s, "s",
                  contribution / u_s if u_s else contribution,
                  note=f"{timer.distribution}; already in the fit's scatter (Type A), not added", in_combined=False,
                  shape=timer.shape)  # fmt: skip


def rate_noise(fit: Fit, head_rad: np.ndarray, aligned_rad: np.ndarray, station: StationInfo,
               order: int) -> tuple[float, int]:  # fmt: skip
    """The windows' rate noise alone, sigma and its dof, for the uncompensated fit's Type A (GUM 4.3.10: an effect
    counted once).

    Uncompensated, the head's angle error puts d(wbar)/d(theta) dtheta(theta) into the rates. The part of it that
    the polynomial absorbs moves the coefficients: that is the harmonics' Type B row. The rest stays in the
    residuals, where eq. 48's sigma would take it for noise and count the same harmonics a second time through
    sigma^2 (X^T X)^-1 (the seed's harmonics at their u leave sigma at 6e-6 rad/s over 2e-7 of noise). So the
    residuals are fitted again with each Type B angle input's rate signature as a further column (each harmonic
    at the head angles, and the head zero: the rate's slope itself); what is left is noise, n - rank dof. With no
    dof left (as many columns as windows) the noise cannot be told from the harmonics and eq. 48's sigma, an
    upper bound, is kept."""
    slope = rate_slope_radps(aligned_rad, fit.values, fit.names, station)
    columns = np.column_stack([regressors(np.cos(aligned_rad), fit.names), slope,
                               slope[:, None] * harmonic_basis(head_rad, order)])  # fmt: skip
    u, sv, _ = np.linalg.svd(columns, full_matrices=False)
    basis = u[:, sv > sv[0] * 1e-10]
    dof = fit.residuals.size - basis.shape[1]
    if dof < 1:
        return fit.sigma_residual, fit.dof
    left = fit.residuals - basis @ (basis.T @ fit.residuals)
    return float(np.sqrt(left @ left / dof)), dof


def uncompensated_budget(
    fit: Fit,
    head_rad: np.ndarray,
    aligned_rad: np.ndarray,
    rates_radps: np.ndarray,
    Tm_s: np.ndarray,
    station: StationInfo,
    order: int,
    zero_sigma_rad: float,
    references: Mapping[str, Reference] | None = None,
) -> Budget:
    """The budget of the static fit at the aligned head angles (head angle + pose + head zero), uncompensated."""
    refs = references if references is not None else default_references()
    h = refs["index_harmonic_rad"]
    lat = refs["latitude_deg"]
    names = harmonic_names(order)
    inputs = [reference_input(n, f"angle-error harmonic {n} (eq. 15), not compensated", 0.0, h) for n in names]
    inputs.append(Input("zero", "head zero of the self-alignment (eq. 56)", 0.0, zero_sigma_rad, "rad",
                        "its own sigma (self-alignment, eq. 56)"))  # fmt: skip
    inputs.append(reference_input("latitude", "latitude", station.latitude_deg, lat))

    def refit(x: Mapping[str, float]) -> np.ndarray:
        angles = aligned_rad + angle_error_rad(head_rad, np.array([x[n] for n in names])) + x["zero"]
        return fit_static(angles, rates_radps, fit.names, replace(station, latitude_deg=x["latitude"])).values

    rows = refit_sources(inputs, refit)
    rows.append(timer_row(fit, aligned_rad, rates_radps, Tm_s, refs["timer_resolution_s"]))
    sigma, dof = rate_noise(fit, head_rad, aligned_rad, station, order)
    cov = fit.cov * (sigma / fit.sigma_residual) ** 2 if fit.sigma_residual > 0 else fit.cov
    return fit_budget(fit.names, fit.values, cov, dof, _units(fit.names), rows,
                      f"eq. 49 at the rate noise alone ({sigma:.2e} rad/s, {dof} dof: the residuals less the "
                      f"angle inputs' signatures; eq. 48's sigma {fit.sigma_residual:.2e} also holds the "
                      "harmonics' unabsorbed part)")  # fmt: skip


def compensated_budget(
    fit: Fit,
    total: Fit,
    fp: FourPoseFit,
    four_pose_windows: list[PoseWindow],
    setup: int,
    pose: int,
    head_rad: np.ndarray,
    rates_radps: np.ndarray,
    Tm_s: np.ndarray,
    station: StationInfo,
    references: Mapping[str, Reference] | None = None,
) -> Budget:
    """The budget of the compensated fit: eq. 49's Type A, the four-pose block, the latitude through both fits."""
    refs = references if references is not None else default_references()
    lat = refs["latitude_deg"]
    angles = fp.instrument_angle_rad("A", setup, pose, head_rad)

    def refit(x: Mapping[str, float]) -> np.ndarray:
        st = replace(station, latitude_deg=x["latitude"])
        four = fit_four_pose(four_pose_windows, fp.terms, fp.order, st)
        return fit_static(four.instrument_angle_rad("A", setup, pose, head_rad), rates_radps, fit.names, st).values

    latitude = reference_input("latitude", "latitude (through the four-pose and the calibration fits)",
                               station.latitude_deg, lat)  # fmt: skip
    block = Source("angle-error harmonics and mounting offset (four-pose fit, Type A)", "A", 0.0, 0.0, "",
                   np.ones(len(fit.names)), dof=float(fp.fit.dof),
                   note=f"their covariance through the compensated angles; {fp.fit.dof} dof of the four-pose fit",
                   block_cov=total.cov - fit.cov)  # fmt: skip
    rows = [block, *refit_sources([latitude], refit)]
    rows.append(timer_row(fit, angles, rates_radps, Tm_s, refs["timer_resolution_s"]))
    return fit_budget(fit.names, fit.values, fit.cov, fit.dof, _units(fit.names), rows,
                      f"eq. 49, {fit.dof} dof; compensated angles")  # fmt: skip
