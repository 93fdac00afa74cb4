"""Whether a design of positions and frequencies can identify (kz, kzz, ky, k3), from the design alone.

The identification (identify.py) fits one static level per position and the
regressors of station/twin/regressors.py; with the static levels profiled out,
its columns are the regressor rows centred within each position (whose static
point has the row 0). The design is singular when those columns are
dependent. The window phases cannot be planned and the kz column lives on the
window edges, so the rows are drawn at random phases (as planning.py does).
"""

from __future__ import annotations

import math

import numpy as np

from station.engine.design_checks import Finding
from station.session import StationInfo
from station.twin.regressors import COEFFICIENTS, integral_regressors
from station.twin.window_means import window_means

PHASE_DRAWS = 8  # sessions of random window phases: singular only if singular in every one (one could be by accident)
RANK_TOL = 1e-9  # a column's norm, or the smallest singular value of the unit-norm columns, relative to the largest:
# dependent columns come out at rounding (ky at -360, 360, 0 deg: 1e-32); identifiable designs stay far above it,
# even ill-conditioned ones (all positions within 6 deg of 0, or 0 and 90 deg: 1e-5; seed 000's 10 positions: 0.7)
SEED000_FIX = "positions spread over the circle, e.g. seed 000's 10 equal angles 0, 36, 72, ..., 324 deg"


def profiled_regressors(
    positions_deg: list[float], freqs_hz: list[float], window_s: float, rng: np.random.Generator
) -> np.ndarray:
    """Regressor rows of every point of one session at random window phases, centred within each position."""
    f = np.asarray(freqs_hz, dtype=float)
    a = StationInfo().amplitude_ratio(f)
    _, index, counts = np.unique(np.round(positions_deg, 9), return_inverse=True, return_counts=True)  # identify.py's
    group = np.repeat(index, len(f))  # the position of each vibration point
    f_all, a_all = np.tile(f, len(positions_deg)), np.tile(a, len(positions_deg))
    t1, t2 = rng.uniform(0, 1 / f_all), rng.uniform(0, 1 / f_all)
    L = integral_regressors(np.radians(np.repeat(positions_deg, len(f))), a_all,
                            *window_means(2 * math.pi * f_all, window_s, t1, t2))  # fmt: skip
    sums = np.stack([np.bincount(group, L[:, j], len(counts)) for j in range(L.shape[1])], axis=1)
    mean = sums / (counts * (len(f) + 1))[:, None]  # over the position's vibration and static points (rows 0)
    return np.vstack([L - mean[group], -mean[index]])


def _dependence(X: np.ndarray) -> str:
    """Why the columns of X are dependent ('' if they are not)."""
    norms = np.linalg.norm(X, axis=0)
    idle = [c for c, n in zip(COEFFICIENTS, norms, strict=True) if n <= RANK_TOL * norms.max()]
    if idle:
        return f"no point excites {', '.join(idle)}"
    _, sv, vt = np.linalg.svd(X / norms, full_matrices=False)
    if sv[-1] > RANK_TOL * sv[0]:
        return ""
    mixed = [c for c, x in zip(COEFFICIENTS, vt[-1], strict=True) if abs(x) > 0.1]
    return f"{', '.join(mixed)} cannot be told apart"


def unidentified(positions_deg: list[float], freqs_hz: list[float], window_s: float) -> str:
    """Why the design cannot identify the coefficients in any session ('' if it can)."""
    n_vibration = len(positions_deg) * len(freqs_hz)
    if n_vibration < len(COEFFICIENTS):
        return f"{n_vibration} vibration points for {len(COEFFICIENTS)} coefficients"
    rng = np.random.default_rng(0)
    whys = [_dependence(profiled_regressors(positions_deg, freqs_hz, window_s, rng)) for _ in range(PHASE_DRAWS)]
    return whys[0] if all(whys) else ""


def check_design(params: dict) -> list[Finding]:
    """A refusal if the identification's design is singular for (kz, kzz, ky, k3)."""
    why = unidentified(params["positions_deg"], params["freqs_hz"], params["window_s"])
    if not why:
        return []
    return [Finding(True, "positions_deg", params["positions_deg"],
                    f"the design is singular for {', '.join(COEFFICIENTS)}: {why}", SEED000_FIX)]  # fmt: skip
