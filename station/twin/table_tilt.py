"""Tilt of the table top as a gradiometer on it reads it (seed 000 6.1.3, eq. 34, Table 7).

About x it is physics.md's parasitic_rotation, alpha_x(psi) = ax0 + axs1 sin psi + axc1 cos psi,
the same rotation that tilts the instrument's input axis. About y and z no effect of the
twin acts on the instrument (the seed finds their influence negligible), so their
harmonics are optional parameters of this model alone, zero unless given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.twin.config import TwinConfig

ARCSEC_RAD = np.pi / (180.0 * 3600.0)  # gradiometers read arc-seconds


@dataclass(frozen=True)
class TiltHarmonics:
    """a0 + as1 sin psi + ac1 cos psi, in rad."""

    a0_rad: float = 0.0
    as1_rad: float = 0.0
    ac1_rad: float = 0.0

    @classmethod
    def about_x(cls, cfg: TwinConfig) -> TiltHarmonics:
        """The twin's parasitic_rotation (zero when the effect is off)."""
        p = ("ax0", "axs1", "axc1")
        return cls(*(cfg.param("parasitic_rotation", k) for k in p))

    def at(self, psi_rad) -> np.ndarray:
        psi = np.asarray(psi_rad, dtype=float)
        return self.a0_rad + self.as1_rad * np.sin(psi) + self.ac1_rad * np.cos(psi)


NO_TILT = TiltHarmonics()


def table_tilt_rad(psi_rad, cfg: TwinConfig, about_y: TiltHarmonics = NO_TILT,
                   about_z: TiltHarmonics = NO_TILT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """(phi_x, phi_y, phi_z) of the table top at crank phase psi."""
    return TiltHarmonics.about_x(cfg).at(psi_rad), about_y.at(psi_rad), about_z.at(psi_rad)
