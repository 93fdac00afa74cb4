"""Self-alignment with the input axis horizontal (seed 003 eqs. 52-56).

Without the nonlinear terms the instrument at instrument angles 90 and 270 deg gives
(physics.md static model, c = cos(90 + theta0) = -sin theta0):

    w90  = k0 - kz sin theta0 + w_ie cos(lam - theta0)
    w270 = k0 + kz sin theta0 - w_ie cos(lam - theta0)

so sin theta0 = (w270 - w90 + 2 w_ie cos lam) / (2 kz) (eq. 55), with kz only roughly known:
at these positions the result hardly depends on it. Eq. 56 propagates the rate, latitude
and kz uncertainties. The two windows are slow (the rate is k0 + ky and the earth rate
alone): about 4 h per revolution at k0 = 4e-4 rad/s.
"""

from __future__ import annotations

import math

from procedures.integral_precession.alignment import Alignment
from station.session import StationInfo

ALIGNMENT_ANGLES_DEG = (90.0, 270.0)  # instrument angles: the input axis horizontal


def horizontal_axis_alignment(
    rate_90_radps: float,
    rate_270_radps: float,
    station: StationInfo,
    *,
    kz_radps_per_g: float,
    sigma_rate_radps: float,
    sigma_latitude_rad: float,
    sigma_kz: float,
) -> Alignment:
    """theta0 by eq. 55 and its uncertainty by eq. 56; k0 + ky from the mean of the two rates."""
    lam = station.latitude_rad
    wie = station.earth_rate_radps
    s = (rate_270_radps - rate_90_radps + 2 * wie * math.cos(lam)) / (2 * kz_radps_per_g)
    theta0 = math.asin(max(-1.0, min(1.0, s)))
    # ds/dw = +-1/(2 kz) for each rate; ds/dlam = -w_ie sin(lam)/kz; ds/dkz = -s/kz; dtheta0/ds = 1/cos(theta0)
    var_s = 2 * (sigma_rate_radps / (2 * kz_radps_per_g)) ** 2
    var_s += (wie * math.sin(lam) / kz_radps_per_g * sigma_latitude_rad) ** 2 + (s / kz_radps_per_g * sigma_kz) ** 2
    sigma = math.sqrt(var_s) / math.cos(theta0)
    k0 = 0.5 * (rate_90_radps + rate_270_radps)  # the earth-rate terms cancel in the sum
    return Alignment("seed 003 eq. 55 (90 and 270 deg)", theta0, sigma, kz_radps_per_g, sigma_kz, k0, math.nan)
