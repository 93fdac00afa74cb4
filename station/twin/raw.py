"""Raw streams of one point: 5 kHz grating samples, every pulse edge, every reference crossing.

Pulse edges are the times at which the precession angle phi(t) crosses a
multiple of one pulse angle (2 pi / 16384), in either direction (an up/down
counter): at 10 Hz the rate reverses every period and phi swings by about
+-0.1 rad, so each period carries about 1200 edges. phi and its rate are
evaluated on a grid of step h = T/512 (the periodic part is computed for one
period and repeated, since h divides T); between grid points phi is the cubic
Hermite interpolant of (phi, rate), whose error is below h^4 max|phi''''| / 384
(6e-12 rad at 10 Hz, i.e. picoseconds in time); grid cells in which the rate
changes sign are split at the cubic's extremum so that each piece is monotone,
and each edge is then solved on its piece by Newton's method. The work is done
in blocks of ~10 s so memory stays bounded for a 560 s window.
"""

from __future__ import annotations

import math

import numpy as np

from station.constants import GRATING_RATE_HZ
from station.errors import InputError
from station.session import RawStreams
from station.twin.config import TwinConfig
from station.twin.inputs import table_position_m
from station.twin.plan import PointSpec
from station.twin.precession import PrecessionWindow

GRID_PER_PERIOD = 512
_STATIC_STEP_S = 0.01
_BLOCK_CELLS = 50_000
GRATING_RESOLUTION_M = 1e-9
_LEVEL_TOL_RAD = 1e-12  # an edge's angle off its level; rounding of phi ~ 314 rad is 6e-14


def grating_samples(
    window: PrecessionWindow,
    cfg: TwinConfig,
    t_end_s: float,
    start_s: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """5 kHz absolute positions z (m) at the read head's sample times in [0, t_end]."""
    dt = 1.0 / GRATING_RATE_HZ
    first = math.ceil(start_s / dt) * dt - start_s  # the read head samples on its own 0.2 ms grid
    t = first + dt * np.arange(math.floor((t_end_s - first) / dt) + 1)
    psi = window.w_radps * t + window.gamma0_rad if window.w_radps else np.zeros_like(t)
    z = table_position_m(psi, window.w_radps, cfg)
    if cfg.noise.grating_noise_m > 0:
        z = z + rng.normal(0.0, cfg.noise.grating_noise_m, z.size)
    return t, np.round(z / GRATING_RESOLUTION_M) * GRATING_RESOLUTION_M


class _GridModel:
    """phi and rate on the grid t = n h; for vibration the periodic part is computed for one period."""

    def __init__(self, window: PrecessionWindow, h: float) -> None:
        self.window, self.h = window, h
        self.periodic = bool(window.w_radps) and window.rate.k.size > 0
        if self.periodic:
            one = np.arange(GRID_PER_PERIOD) * h
            base = PrecessionWindow(window.rate, window.w_radps, window.gamma0_rad)  # no offset, no drift
            self.per_phi = base.phi_rad(one) - base.rate.c0_radps * one
            self.per_rate = base.rate_radps(one) - base.rate.c0_radps

    def values(self, n0: int, n1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = np.arange(n0, n1 + 1)
        t = n * self.h
        w = self.window
        if not self.periodic:
            return t, w.phi_rad(t), w.rate_radps(t)
        idx = n % GRID_PER_PERIOD
        phi = w.mean_rate_radps * t + 0.5 * w.drift_radps2 * t * t + self.per_phi[idx]
        rate = w.mean_rate_radps + w.drift_radps2 * t + self.per_rate[idx]
        return t, phi, rate


def _edges_in_cells(t, phi, rate, h, q):
    """Pulse edges inside the cells [t_i, t_i+1] of one block, in time order.

    On each cell phi is the cubic Hermite interpolant c0 + c1 s + c2 s^2 + c3 s^3
    of (phi, rate) at its ends, s in [0, 1]. Cells where the rate changes sign
    are split at the cubic's extremum into two monotone pieces.
    """
    p0, p1, r0, r1 = phi[:-1], phi[1:], h * rate[:-1], h * rate[1:]
    c0, c1 = p0, r0
    c2 = 3.0 * (p1 - p0) - 2.0 * r0 - r1
    c3 = 2.0 * (p0 - p1) + r0 + r1
    n = p0.size
    turning = np.sign(r0) * np.sign(r1) < 0
    s_ext = np.full(n, 1.0)
    if turning.any():
        s_ext[turning] = _extremum_fraction(c1[turning], c2[turning], c3[turning])
    # Pieces in time order: every cell gives [0, s_ext]; a turning cell also [s_ext, 1] right after it.
    n_pieces = 1 + turning.astype(np.int64)
    cell = np.repeat(np.arange(n), n_pieces)
    second = np.zeros(cell.size, dtype=bool)
    second[np.cumsum(n_pieces)[turning] - 1] = True
    s_a = np.where(second, s_ext[cell], 0.0)
    s_b = np.where(second, 1.0, s_ext[cell])
    va = _cubic(c0[cell], c1[cell], c2[cell], c3[cell], s_a)
    vb = _cubic(c0[cell], c1[cell], c2[cell], c3[cell], s_b)
    up = vb >= va
    lo_level = np.where(up, np.floor(va / q) + 1, np.ceil(vb / q))
    hi_level = np.where(up, np.floor(vb / q), np.ceil(va / q) - 1)
    count = np.maximum(hi_level - lo_level + 1, 0).astype(np.int64)
    piece = np.repeat(np.arange(cell.size), count)
    offsets = np.arange(piece.size) - np.repeat(np.cumsum(count) - count, count)
    up_e = up[piece]
    # Rising pieces cross their levels upwards in time, falling pieces downwards.
    level = np.where(up_e, lo_level[piece] + offsets, hi_level[piece] - offsets) * q
    c = cell[piece]
    e0, e1, e2, e3 = c0[c], c1[c], c2[c], c3[c]
    s = _solve_levels(e0, e1, e2, e3, level, s_a[piece], s_b[piece], va[piece], vb[piece])
    return t[c] + s * h, np.where(up_e, 1, -1).astype(np.int8)


def _solve_levels(e0, e1, e2, e3, level, a, b, fa, fb):
    """Root s in [a, b] of cubic(s) = level on monotone pieces.

    Two Newton steps from the secant start reach ~1e-13 s for almost every edge
    (quadratic convergence). Near a turning point the slope vanishes and Newton
    slows, so the few edges still off their level by more than 1e-12 rad go on
    with Newton safeguarded by bisection inside their bracket.
    """
    df = fb - fa
    s = a + (b - a) * np.where(df != 0, (level - fa) / np.where(df != 0, df, 1.0), 0.5)
    for _ in range(2):
        der = (3.0 * e3 * s + 2.0 * e2) * s + e1
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.clip(s - (_cubic(e0, e1, e2, e3, s) - level) / der, a, b)
    s = np.where(np.isfinite(s), s, 0.5 * (a + b))
    slow = np.flatnonzero(np.abs(_cubic(e0, e1, e2, e3, s) - level) > _LEVEL_TOL_RAD)
    if slow.size:
        s[slow] = _bracketed(
            e0[slow], e1[slow], e2[slow], e3[slow], level[slow], a[slow], b[slow], fb[slow] >= fa[slow]
        )
    return s


def _bracketed(e0, e1, e2, e3, level, lo, hi, rising):
    s = 0.5 * (lo + hi)
    for _ in range(100):
        val = _cubic(e0, e1, e2, e3, s) - level
        if np.all(np.abs(val) <= _LEVEL_TOL_RAD):
            break
        below = np.where(rising, val < 0, val > 0)
        lo, hi = np.where(below, s, lo), np.where(below, hi, s)
        der = (3.0 * e3 * s + 2.0 * e2) * s + e1
        with np.errstate(divide="ignore", invalid="ignore"):
            new = s - val / der
        s = np.where((new > lo) & (new < hi), new, 0.5 * (lo + hi))
    return s


def _cubic(c0, c1, c2, c3, s):
    return ((c3 * s + c2) * s + c1) * s + c0


def _extremum_fraction(c1, c2, c3):
    """Fraction s in (0, 1) where c1 + 2 c2 s + 3 c3 s^2 = 0 (the rate changes sign)."""
    A, B, C = 3.0 * c3, 2.0 * c2, c1
    disc = np.sqrt(np.maximum(B * B - 4 * A * C, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        # Stable quadratic roots: q = -(B + sign(B) disc) / 2, roots q / A and C / q.
        qq = -0.5 * (B + np.copysign(disc, B))
        roots = np.stack([qq / A, C / qq])
    inside = (roots > 0) & (roots < 1)
    pick = np.where(inside[0], roots[0], roots[1])
    return np.clip(np.where(inside.any(axis=0), pick, 0.5), 1e-12, 1 - 1e-12)


def pulse_edges(
    window: PrecessionWindow, t_end_s: float, pulse_angle_rad: float, phase_offset_rad: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Every edge (time, direction +1/-1) of the output pulses in [0, t_end].

    Edges are where phi(t) + offset crosses a multiple of the pulse angle; with
    no offset, t = 0 is itself an edge (the window's opening edge) and is included.
    """
    h = 2.0 * math.pi / window.w_radps / GRID_PER_PERIOD if window.w_radps else _STATIC_STEP_S
    n_cells = math.ceil(t_end_s / h)
    opening = phase_offset_rad is None
    offset = 0.0 if opening else phase_offset_rad
    grid = _GridModel(window, h)
    times = [np.zeros(1)] if opening else []
    dirs = [np.ones(1, dtype=np.int8)] if opening else []
    for n0 in range(0, n_cells, _BLOCK_CELLS):
        t, phi, rate = grid.values(n0, min(n0 + _BLOCK_CELLS, n_cells))
        et, ed = _edges_in_cells(t, phi + offset, rate, h, pulse_angle_rad)
        keep = (et > 0) & (et <= t_end_s)
        times.append(et[keep])
        dirs.append(ed[keep])
    if not times:
        return np.zeros(0), np.zeros(0, dtype=np.int8)
    return np.concatenate(times), np.concatenate(dirs)


MAX_RAW_SAMPLES = 60_000_000  # grating samples plus pulse edges: about 1.5 GB of float64 arrays


class RawStreamsTooLargeError(InputError):
    """Raw streams of a window that would not fit in memory."""


def check_raw_size(window: PrecessionWindow, t_end_s: float, pulse_angle_rad: float) -> None:
    """Refuse raw streams longer than MAX_RAW_SAMPLES (grating samples plus estimated pulse edges)."""
    n_grating = t_end_s * GRATING_RATE_HZ
    if window.w_radps and window.rate.k.size:
        psi = np.linspace(0.0, 2 * np.pi, 256, endpoint=False)
        probe = PrecessionWindow(window.rate, window.w_radps, 0.0, window.offset_radps)
        mean_abs_rate = float(np.mean(np.abs(probe.rate_radps(psi / window.w_radps))))
    else:
        mean_abs_rate = abs(window.mean_rate_radps)
    n_edges = mean_abs_rate * t_end_s / pulse_angle_rad
    if n_grating + n_edges > MAX_RAW_SAMPLES:
        raise RawStreamsTooLargeError(
            f"raw streams of a {t_end_s:.0f} s window: {n_grating:.3g} grating samples and about {n_edges:.3g} "
            f"pulse edges exceed {MAX_RAW_SAMPLES:.3g} (about 1.5 GB); record raw streams of shorter windows "
            "(positions away from 90 and 270 deg) or without raw=True"
        )


def raw_streams(
    window: PrecessionWindow,
    cfg: TwinConfig,
    spec: PointSpec,
    t_end_s: float,
    start_s: float,
    rng: np.random.Generator,
    reference_t: np.ndarray | None,
) -> RawStreams:
    """Grating record, pulse edges and reference crossings over the window [0, t_end].

    RawStreamsTooLargeError before anything is allocated if they would exceed MAX_RAW_SAMPLES
    (a static window near 90 deg lasts hours; under vibration its up/down edges are millions).
    """
    check_raw_size(window, t_end_s, cfg.station.pulse_angle_rad)
    g_t, g_z = grating_samples(window, cfg, t_end_s, start_s, rng)
    p_t, p_dir = pulse_edges(window, t_end_s, cfg.station.pulse_angle_rad)
    ref = None
    if reference_t is not None:
        ref = reference_t[(reference_t >= 0) & (reference_t <= t_end_s)]
    return RawStreams(g_t, g_z, p_t, p_dir, ref)
