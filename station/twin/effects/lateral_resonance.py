"""lateral_resonance: lateral motion near a structural resonance, seen through kx (seed 000 6.1.4).

a_lat = L(f) A0 w^2 sin(psi + phiL), L(f) = L0 / sqrt((1 - (f/fr)^2)^2 + (f/(Q fr))^2), and the instrument rate
gains kx aO^2 (physics.md, table and rate model).
"""

from __future__ import annotations

import numpy as np

from station.twin.effects.base import Effect, Param, Params, Terms


def gain(p: Params, freq_hz: float) -> float:
    """L(f) = L0 / sqrt((1 - (f/fr)^2)^2 + (f/(Q fr))^2)."""
    r = freq_hz / p["fr"]
    return p["L0"] / float(np.sqrt((1.0 - r * r) ** 2 + (r / p["Q"]) ** 2))


def lateral_accel_mps2(p: Params, psi: np.ndarray, w_radps: float, A0_m: float) -> np.ndarray:
    return gain(p, w_radps / (2.0 * np.pi)) * A0_m * w_radps**2 * np.sin(psi + p["phiL"])


def rate_radps(p: Params, a_i: np.ndarray, a_p: np.ndarray, a_o: np.ndarray) -> np.ndarray:
    return p["kx"] * a_o**2


def check(p: Params) -> str:
    return "" if p["fr"] > 0 and p["Q"] > 0 else f"fr = {p['fr']!r} and Q = {p['Q']!r} must be > 0"


EFFECT = Effect(
    name="lateral_resonance",
    cause="lateral motion near a structural resonance, seen through kx (seed 000 6.1.4)",
    params={
        "L0": Param("1", nominal=0.01),  # 1 % lateral motion
        "fr": Param("Hz", default=30.0),
        "Q": Param("1", default=10.0),
        "phiL": Param("rad"),
        # seed 000 6.1.4: kx about 1e-5 rad/s/g^2; kx L0^2 up to 5e-7 (kx 2e-4 at 5 % lateral motion).
        "kx": Param("rad/s/g^2", typical=1e-5, bound=5e-3),
    },
    injection={"kx": 1e-5},  # with L0 = 0.01, fr and Q at the twin's defaults
    notes="only kx L0^2 is seen: L0 is fixed, fr and Q come from the twin, phiL has no effect on window means",
    explanation="The table moves sideways along the output axis near a structural resonance at fr, and the "
    "instrument's kx aO^2 term turns it into rate. Measure the lateral motion with an accelerometer along OA over "
    "the frequencies, then stiffen the fixture or stay clear of fr.",
    separating="more vibration frequencies, nearer fr, separate the resonance's shape from the frequency shape of "
    "the calibrated terms",
    terms=Terms(lateral_accel_mps2=lateral_accel_mps2, rate_radps=rate_radps),
    pulse_phase="phiL",  # kx aO^2 has window mean kx L^2 a^2 / 2 whatever phiL; its 2nd rate harmonic turns with 2 phiL
    check=check,
)
