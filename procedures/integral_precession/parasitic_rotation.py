"""Parasitic rotation of the table top from gradiometer readings (seed 000 6.1.3, eq. 34, Table 7).

alpha(psi) = a0 + as1 sin psi + ac1 cos psi about each axis (physics.md's parasitic_rotation
for x). Eq. 34 takes N readings at the crank phases 2 pi i / N:

    as1 = (2 / N) sum_i phi(2 pi i / N) sin(2 pi i / N),  ac1 = (2 / N) sum_i phi(2 pi i / N) cos(2 pi i / N)

Readings that are not exactly at those phases (a polled instrument answers a little
late) are fitted by least squares on 1, sin psi, cos psi, which is eq. 34 when they are
equally spaced over whole turns.
Angles are in arc-seconds here, as the instrument reads them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from procedures.integral_precession.table_motion import CrankPhase, FourierFit, fourier_fit, phased_fourier_fit

AXES = ("x", "y", "z")

# Seed 000 Table 7: gradiometer readings (arc-seconds) at six crank-disk angles (deg).
TABLE7_ANGLE_DEG = (0.0, 60.0, 120.0, 180.0, 240.0, 300.0)
TABLE7_ARCSEC = {
    "x": (15.7, 16.6, 16.725, 17.8, 16.925, 15.725),
    "y": (0.15, -1.725, -1.20, 0.90, 1.50, 0.75),
    "z": (10.08, 10.09, 9.74, 10.45, 10.03, 10.23),
}
# What the seed reports from them (arc-seconds).
SEED_HARMONICS_ARCSEC = {"x": (-0.92, 0.19), "y": (-0.46, -1.49), "z": (0.16, 0.16)}


def table7_psi_rad(angle_deg) -> np.ndarray:
    """Crank phase psi of Table 7's crank-disk angle: psi = 90 deg - angle.

    The seed counts the disk angle from top dead centre (z at its maximum, psi = 90 deg
    in physics.md) against the crank's sense of turning; with this reading eq. 34 gives
    the seed's axs1 = -0.92", axc1 = 0.19", ays1 = -0.46", ayc1 = -1.49" from Table 7.
    """
    return np.radians(90.0 - np.asarray(angle_deg, dtype=float))


@dataclass(frozen=True)
class RotationHarmonics:
    """a0 + as1 sin psi + ac1 cos psi about one axis, in arc-seconds, with standard uncertainties."""

    axis: str
    a0: float
    as1: float
    ac1: float
    sigma_a0: float
    sigma_as1: float
    sigma_ac1: float
    residual_rms: float
    n_readings: int

    @classmethod
    def of(cls, axis: str, fit: FourierFit, n: int) -> RotationHarmonics:
        return cls(axis, fit.mean, float(fit.sin[0]), float(fit.cos[0]), fit.sigma_mean, float(fit.sigma_sin[0]),
                   float(fit.sigma_cos[0]), fit.residual_rms, n)  # fmt: skip

    def to_json(self) -> dict:
        """Keys as the seed names them, e.g. axs1_arcsec and sigma_axs1_arcsec."""
        out: dict = {}
        for attr, suffix in (("a0", "0"), ("as1", "s1"), ("ac1", "c1")):
            out[f"a{self.axis}{suffix}_arcsec"] = getattr(self, attr)
            out[f"sigma_a{self.axis}{suffix}_arcsec"] = getattr(self, f"sigma_{attr}")
        return out | {"residual_rms_arcsec": self.residual_rms, "n_readings": self.n_readings}


def eq34(psi_rad: np.ndarray, phi: np.ndarray) -> tuple[float, float, float]:
    """Seed 000 eq. 34 on N readings at N phases equally spaced over a turn (2 pi i / N there): (a0, as1, ac1)."""
    psi = np.asarray(psi_rad, dtype=float)
    phi = np.asarray(phi, dtype=float)
    k = 2.0 / phi.size
    return float(phi.mean()), float(k * np.sum(phi * np.sin(psi))), float(k * np.sum(phi * np.cos(psi)))


def fit_rotation(axis: str, t_s: np.ndarray, phi_arcsec: np.ndarray, phase: CrankPhase) -> RotationHarmonics:
    """Least-squares equivalent of eq. 34 at each reading's crank phase (phase uncertainty included)."""
    return RotationHarmonics.of(axis, phased_fourier_fit(t_s, phi_arcsec, phase, 1), int(np.size(t_s)))


def fit_at_phases(axis: str, psi_rad: np.ndarray, phi_arcsec: np.ndarray) -> RotationHarmonics:
    """Least squares at known phases (the seed's own table)."""
    return RotationHarmonics.of(axis, fourier_fit(psi_rad, phi_arcsec, 1), int(np.size(psi_rad)))


def slot_means(psi_rad: np.ndarray, phi: np.ndarray, n_slots: int) -> tuple[np.ndarray, np.ndarray]:
    """Readings grouped by the nearest of the phases 2 pi i / n_slots: (mean phase offset in rad, mean reading).

    The Table 7 view of a series: each slot's mean over the turns, and how far its
    readings lay from the slot's nominal phase on average.
    """
    step = 2 * np.pi / n_slots
    psi = np.mod(np.asarray(psi_rad, dtype=float), 2 * np.pi)
    slot = np.rint(psi / step).astype(int) % n_slots
    offset = np.angle(np.exp(1j * (psi - slot * step)))
    phi = np.asarray(phi, dtype=float)
    means = np.full(n_slots, np.nan)
    offsets = np.full(n_slots, np.nan)
    for i in range(n_slots):
        sel = slot == i
        if sel.any():
            means[i] = phi[sel].mean()
            offsets[i] = offset[sel].mean()
    return offsets, means
