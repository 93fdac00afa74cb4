"""The orthogonal 4-pose method with two PIGAs: the head's angle-error harmonics (seed 003 eqs. 16-42).

Both PIGAs see the head's angle error dtheta(theta) = sum_k ck cos k theta + sk sin k theta
(physics.md, index_harmonics; seed 003 eq. 15 keeps k <= 3). One instrument alone cannot
tell it from its own coefficients: -kz sin(theta) dtheta(theta) holds cos-harmonics that its
polynomial in cos theta absorbs (s1 into k0 + ky and kzz - ky, s2 into kz and k3). PIGA B,
90 deg away, has a polynomial in sin theta and absorbs the others; the second setup (A in
pose 4, B in pose 3) turns each instrument by 90 deg so that what its polynomial absorbed in
setup 1 now changes sign against it (seed 003 eqs. 40-42). The seed solves this in stages
(scale factors from the circle of the two outputs, eqs. 18-27; then the angle at each
position and its harmonics, eqs. 29-42); here every window of both setups and both
instruments goes into one least squares of

    wbar = P_X(cos phi) - w_ie sin(lam - phi),  phi = theta + dtheta(theta) + P_pose + delta_(X, setup)

for the harmonics, each instrument's coefficients and the mounting offset of each instrument
in each setup (a constant angle error is one of those offsets), so that no stage's error is
passed on unaccounted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from procedures.integral_precession.alignment import earth_rate_along_ia
from procedures.multiposition.lsq import Fit, solve
from procedures.multiposition.static_model import fit_static, rate_slope_radps, regressors
from station.least_squares import FitError
from station.session import StationInfo
from station.twin.fixture import pose_rad


@dataclass(frozen=True)
class PoseWindow:
    """One static window of one instrument: head encoder angle, measured rate, and what it was for."""

    instrument: str  # "A" or "B"
    setup: int
    pose: int
    theta_rad: float
    rate_radps: float
    block: str = "four_pose"  # four_pose, alignment, or calibration <scheme>
    Tm_s: float = float("nan")


def harmonic_names(order: int) -> tuple[str, ...]:
    return tuple(f"{p}{k}" for k in range(1, order + 1) for p in ("c", "s"))


def harmonic_basis(theta_rad: np.ndarray, order: int) -> np.ndarray:
    """Columns cos k theta, sin k theta, k = 1 .. order."""
    theta = np.asarray(theta_rad, dtype=float)
    return np.column_stack([f(k * theta) for k in range(1, order + 1) for f in (np.cos, np.sin)])


def angle_error_rad(theta_rad: np.ndarray, harmonics_rad: np.ndarray) -> np.ndarray:
    """dtheta(theta) = sum_k ck cos k theta + sk sin k theta (seed 003 eq. 15)."""
    h = np.asarray(harmonics_rad, dtype=float)
    return harmonic_basis(theta_rad, h.size // 2) @ h


@dataclass(frozen=True)
class FourPoseFit:
    fit: Fit
    terms: tuple[str, ...]
    order: int
    instruments: tuple[str, ...]
    groups: tuple[tuple[str, int], ...]  # (instrument, setup) of each mounting offset

    @property
    def harmonics_rad(self) -> np.ndarray:
        return self.fit.values[-2 * self.order :]

    @property
    def harmonic_sigmas_rad(self) -> np.ndarray:
        return self.fit.sigmas[-2 * self.order :]

    def offset_rad(self, instrument: str, setup: int) -> float:
        return self.fit.value(offset_name(instrument, setup))[0]

    def coefficients(self, instrument: str) -> dict[str, tuple[float, float]]:
        return {t: self.fit.value(f"{instrument} {t}") for t in self.terms}

    def angle_parameters(self, instrument: str, setup: int) -> tuple[str, ...]:
        """The fitted parameters an instrument's compensated angle depends on: its offset and the harmonics."""
        return (offset_name(instrument, setup), *harmonic_names(self.order))

    def angle_covariance(self, instrument: str, setup: int) -> np.ndarray:
        idx = [self.fit.names.index(n) for n in self.angle_parameters(instrument, setup)]
        return self.fit.cov[np.ix_(idx, idx)]

    def angle_derivatives(self, theta_rad: np.ndarray) -> np.ndarray:
        """d(compensated angle)/d(offset, harmonics) at head angles theta."""
        theta = np.asarray(theta_rad, dtype=float)
        return np.hstack([np.ones((theta.size, 1)), harmonic_basis(theta, self.order)])

    def instrument_angle_rad(self, instrument: str, setup: int, pose: int, theta_rad: np.ndarray) -> np.ndarray:
        """The compensated angle of an instrument's input axis: theta + dtheta(theta) + P_pose + delta."""
        theta = np.asarray(theta_rad, dtype=float)
        return theta + angle_error_rad(theta, self.harmonics_rad) + pose_rad(pose) + self.offset_rad(instrument, setup)


def offset_name(instrument: str, setup: int) -> str:
    return f"delta {instrument} setup {setup}"


def fit_four_pose(windows: list[PoseWindow], terms: tuple[str, ...], order: int, station: StationInfo) -> FourPoseFit:
    """Harmonics, coefficients and mounting offsets from the windows of both instruments in both setups."""
    if not windows:
        raise FitError("no four-pose windows")
    inst = np.array([w.instrument for w in windows])
    theta = np.array([w.theta_rad for w in windows])
    rate = np.array([w.rate_radps for w in windows])
    nominal = theta + np.array([pose_rad(w.pose) for w in windows])
    instruments = tuple(sorted(set(inst)))
    groups = tuple(sorted({(w.instrument, w.setup) for w in windows}))
    group_of = np.array([groups.index((w.instrument, w.setup)) for w in windows])
    p = len(terms)
    names = (*(f"{i} {t}" for i in instruments for t in terms), *(offset_name(*g) for g in groups),
             *harmonic_names(order))  # fmt: skip
    rows_of = [inst == i for i in instruments]
    H = harmonic_basis(theta, order)
    G = np.eye(len(groups))[group_of]
    n_coef = p * len(instruments)

    def unpack(x: np.ndarray):
        coefs = x[:n_coef].reshape(len(instruments), p)
        phi = nominal + G @ x[n_coef : n_coef + len(groups)] + H @ x[n_coef + len(groups) :]
        return coefs, phi

    def residuals(x: np.ndarray) -> np.ndarray:
        coefs, phi = unpack(x)
        X = regressors(np.cos(phi), terms)
        model = np.select(rows_of, [X @ k for k in coefs])
        return model - earth_rate_along_ia(phi, station) - rate

    def jacobian(x: np.ndarray) -> np.ndarray:
        coefs, phi = unpack(x)
        X = regressors(np.cos(phi), terms)
        dphi = np.select(rows_of, [rate_slope_radps(phi, k, terms, station) for k in coefs])
        J_coef = np.hstack([X * m[:, None] for m in rows_of])
        return np.hstack([J_coef, G * dphi[:, None], H * dphi[:, None]])

    x0 = np.zeros(len(names))
    for j, rows in enumerate(rows_of):
        x0[j * p : (j + 1) * p] = fit_static(nominal[rows], rate[rows], terms, station).values
    fit = solve(residuals, jacobian, x0, names)
    return FourPoseFit(fit, terms, order, instruments, groups)
