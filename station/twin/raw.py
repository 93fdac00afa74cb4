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
from station.session import RawStreams
from station.twin.config import TwinConfig
from station.twin.inputs import table_position_m
from station.twin.measurement import PointSpec
from station.twin.precession import PrecessionWindow

GRID_PER_PERIOD = 512
_STATIC_STEP_S = 0.01
_BLOCK_CELLS = 50_000
GRATING_RESOLUTION_M = 1e-9


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
    t = first + dt * np.arange(int(math.floor((t_end_s - first) / dt)) + 1)
    psi = window.w_radps * t + window.gamma0_rad if window.w_radps else np.zeros_like(t)
    z = table_position_m(psi, window.w_radps, cfg)
    if cfg.noise.grating_noise_m > 0:
        z = z + rng.normal(0.0, cfg.noise.grating_noise_m, z.size)
    return t, np.round(z / GRATING_RESOLUTION_M) * GRATING_RESOLUTION_M


def _grid_values(window: PrecessionWindow, t: np.ndarray, n0: int) -> tuple[np.ndarray, np.ndarray]:
    """phi and rate on grid points t = (n0 + i) h, reusing one period of the periodic part."""
    if not window.w_radps or window.rate.k.size == 0:
        return window.phi_rad(t), window.rate_radps(t)
    period = 2.0 * math.pi / window.w_radps
    one = np.arange(GRID_PER_PERIOD) * (period / GRID_PER_PERIOD)
    base = PrecessionWindow(window.rate, window.w_radps, window.gamma0_rad)  # no offset, no drift
    per_phi = base.phi_rad(one) - base.rate.c0_radps * one
    per_rate = base.rate_radps(one) - base.rate.c0_radps
    idx = (n0 + np.arange(t.size)) % GRID_PER_PERIOD
    mean_phi = window.mean_rate_radps * t + 0.5 * window.drift_radps2 * t * t
    mean_rate = window.mean_rate_radps + window.drift_radps2 * t
    return mean_phi + per_phi[idx], mean_rate + per_rate[idx]


def _hermite(p0, p1, r0, r1, h, s):
    """Cubic Hermite value and derivative (per unit time) at fraction s of a cell."""
    s2, s3 = s * s, s * s * s
    val = (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * r0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * h * r1
    der = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * h * r0 + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * h * r1) / h
    return val, der


def _edges_in_cells(t, phi, rate, h, q):
    """Pulse edges inside the cells [t_i, t_i+1] of one block."""
    p0, p1, r0, r1 = phi[:-1], phi[1:], rate[:-1], rate[1:]
    n = p0.size
    # Split cells where the rate changes sign at the Hermite cubic's extremum.
    s_split = np.full(n, np.nan)
    turning = np.flatnonzero(np.sign(r0) * np.sign(r1) < 0)
    if turning.size:
        s_split[turning] = _extremum_fraction(p0[turning], p1[turning], r0[turning], r1[turning], h)
    cell = np.concatenate([np.arange(n), turning])
    s_a = np.concatenate([np.zeros(n), s_split[turning]])
    s_b = np.concatenate([np.where(np.isnan(s_split), 1.0, s_split), np.ones(turning.size)])
    va, _ = _hermite(p0[cell], p1[cell], r0[cell], r1[cell], h, s_a)
    vb, _ = _hermite(p0[cell], p1[cell], r0[cell], r1[cell], h, s_b)
    up = vb >= va
    lo_level = np.where(up, np.floor(va / q) + 1, np.ceil(vb / q))
    hi_level = np.where(up, np.floor(vb / q), np.ceil(va / q) - 1)
    count = np.maximum(hi_level - lo_level + 1, 0).astype(np.int64)
    piece = np.repeat(np.arange(cell.size), count)
    offsets = np.arange(piece.size) - np.repeat(np.cumsum(count) - count, count)
    level = (lo_level[piece] + offsets) * q
    c, a, b = cell[piece], s_a[piece], s_b[piece]
    fa, fb = va[piece], vb[piece]
    s = a + (b - a) * np.where(fb != fa, (level - fa) / np.where(fb != fa, fb - fa, 1.0), 0.5)
    for _ in range(4):
        val, der = _hermite(p0[c], p1[c], r0[c], r1[c], h, s)
        step = np.where(der != 0, (val - level) / np.where(der != 0, der, 1.0) / h, 0.0)
        s = np.clip(s - step, a, b)
    direction = np.where(up[piece], 1, -1).astype(np.int8)
    times = t[c] + s * h
    order = np.argsort(times, kind="stable")
    return times[order], direction[order]


def _extremum_fraction(p0, p1, r0, r1, h):
    """Fraction s in (0, 1) where the Hermite cubic's derivative vanishes (rate changes sign)."""
    # derivative * h = A s^2 + B s + C
    A = 6 * p0 + 3 * h * r0 - 6 * p1 + 3 * h * r1
    B = -6 * p0 - 4 * h * r0 + 6 * p1 - 2 * h * r1
    C = h * r0
    disc = np.sqrt(np.maximum(B * B - 4 * A * C, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        roots = np.stack([(-B - disc) / (2 * A), (-B + disc) / (2 * A)])
        linear = -C / B
    roots = np.where(np.abs(A) > 1e-300, roots, linear)
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
    if window.w_radps:
        h = 2.0 * math.pi / window.w_radps / GRID_PER_PERIOD
    else:
        h = _STATIC_STEP_S
    n_cells = int(math.ceil(t_end_s / h))
    opening = phase_offset_rad is None
    offset = 0.0 if opening else phase_offset_rad
    times = [np.zeros(1)] if opening else []
    dirs = [np.ones(1, dtype=np.int8)] if opening else []
    for n0 in range(0, n_cells, _BLOCK_CELLS):
        n1 = min(n0 + _BLOCK_CELLS, n_cells)
        t = np.arange(n0, n1 + 1) * h
        phi, rate = _grid_values(window, t, n0)
        et, ed = _edges_in_cells(t, phi + offset, rate, h, pulse_angle_rad)
        keep = (et > 0) & (et <= t_end_s)
        times.append(et[keep])
        dirs.append(ed[keep])
    if not times:
        return np.zeros(0), np.zeros(0, dtype=np.int8)
    return np.concatenate(times), np.concatenate(dirs)


def raw_streams(
    window: PrecessionWindow,
    cfg: TwinConfig,
    spec: PointSpec,
    t_end_s: float,
    start_s: float,
    rng: np.random.Generator,
    reference_t: np.ndarray | None,
) -> RawStreams:
    """Grating record, pulse edges and reference crossings over the window [0, t_end]."""
    g_t, g_z = grating_samples(window, cfg, t_end_s, start_s, rng)
    p_t, p_dir = pulse_edges(window, t_end_s, cfg.station.pulse_angle_rad)
    ref = None
    if reference_t is not None:
        ref = reference_t[(reference_t >= 0) & (reference_t <= t_end_s)]
    return RawStreams(g_t, g_z, p_t, p_dir, ref)
