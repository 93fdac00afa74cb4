"""The physical world of one measurement window, written from physics.md alone.

Everything is solved numerically, not from closed forms:

- the precession angle phi(t) = integral of w_out is a composite Gauss-Legendre quadrature
  (`GL_NODES` nodes per panel, `PANELS` panels per vibration period, panel edges also put at the
  kinks of |aI| terms, found by a bracketed root search), repeated period by period since w_out
  is periodic in the crank phase; session-time terms (drifts, steps, transients) are added as
  their exact integrals;
- the first passage |phi(t)| = 2 pi P / 16384 is a bracketed root search (scipy brentq) on the
  monotone piece, between two zeros of w_out, on which phi first reaches the target;
- reference crossings come from the table motion itself (psi = 0 mod 2 pi), shifted by the read
  head's latency; every stamped event gets timing jitter and is counted in 50 ns ticks;
- raw pulse edges are solved event by event (phi = k 2 pi / 16384 on each monotone piece, a
  safeguarded Newton iteration), grating samples come from the motion formula z(t).

Frames and signs follow physics.md: IA = (0, -sin theta, cos theta), a_z = z'', aI = (g + a_z)
cos theta_e / g, wI = w_ie sin(lam - theta_e), the crank rests at psi = 0 in a static test.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import brentq, elementwise

G_MPS2 = 9.8016093
EARTH_RATE_RADPS = 7.292115e-5
LATITUDE_DEG = 39.94
A0_M = 0.03
PULSES_PER_REV = 16384
PULSE_RAD = 2.0 * math.pi / PULSES_PER_REV
TICK_S = 50e-9
GRATING_HZ = 5000.0
GRATING_LSB_M = 1e-9  # the absolute grating's resolution: samples are rounded to 1 nm

GL_NODES = 12
PANELS = 32
_ROOT_GRID = 512  # samples of w_out per period used to bracket its zeros
_XTOL_S = 1e-13
_X_GL, _W_GL = np.polynomial.legendre.leggauss(GL_NODES)
ARCSEC_RAD = math.pi / (180.0 * 3600.0)


@dataclass
class Coefficients:
    """Instrument rate-model coefficients (rad/s, rad/s/g, ...), physics.md plus out-of-library terms."""

    k0: float
    kz: float
    kzz: float
    ky: float
    k3: float
    koq: float = 0.0  # aI|aI|
    kx: float = 0.0  # aO^2
    kip: float = 0.0  # aI aP
    k4: float = 0.0  # aI^4 (out of library)
    kz_asym: float = 0.0  # kz is kz (1 + kz_asym) for aI < 0 (out of library)

    def as_dict(self) -> dict[str, float]:
        return dict(self.__dict__)


@dataclass
class Perturbation:
    """Every parameter of the world that the nominal model sets to zero (radians, metres, seconds)."""

    z0_m: float = 0.0  # Zs1 = z0 + z1 w
    z1_ms: float = 0.0
    zc1_m: float = 0.0
    zs2_m: float = 0.0
    zc2_m: float = 0.0
    zs3_m: float = 0.0
    zc3_m: float = 0.0
    ax0_rad: float = 0.0  # alpha_x = ax0 + axs1 sin psi + axc1 cos psi + ax2s sin 2psi + ax2c cos 2psi
    axs1_rad: float = 0.0
    axc1_rad: float = 0.0
    ax2s_rad: float = 0.0
    ax2c_rad: float = 0.0
    L0: float = 0.0  # lateral resonance: a_lat = L(f) A0 w^2 sin(psi + phiL)
    fr_hz: float = 10.0
    Q: float = 10.0
    phiL_rad: float = 0.0
    idx_c_rad: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    idx_s_rad: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    mount_rad: float = 0.0
    latency_s: float = 0.0
    eps_f: float = 0.0
    eps_f2_at10hz: float = 0.0  # frequency error eps_f2 (f / 10 Hz)^2 (out of library)
    drift_radps_per_s: float = 0.0  # k0 + d t_session
    quad_radps_per_s2: float = 0.0  # + q t_session^2 (out of library)
    step_radps: float = 0.0  # + b for t_session >= step_time_s (out of library)
    step_time_s: float = 0.0
    transient_radps: float = 0.0  # + b exp(-(t - t_move) / tau) after each index move (out of library)
    transient_tau_s: float = 600.0
    backlash_rad: float = 0.0  # indexing head lands +-backlash/2 off, by the direction it came from (out of library)
    kz_drift_per_s: float = 0.0  # kz (1 + ks t_window_start): scale factor drift (out of library)

    def index_error_rad(self, theta_rad: float) -> float:
        """dtheta_idx(theta) = sum_k ck cos k theta + sk sin k theta, k = 1..4 (physics.md, seed 003)."""
        return sum(
            c * math.cos(k * theta_rad) + s * math.sin(k * theta_rad)
            for k, (c, s) in enumerate(zip(self.idx_c_rad, self.idx_s_rad, strict=True), start=1)
        )

    def true_freq_hz(self, f_cmd_hz: float) -> float:
        """w = w_cmd (1 + eps_f), plus the out-of-library error growing with f^2."""
        return f_cmd_hz * (1.0 + self.eps_f + self.eps_f2_at10hz * (f_cmd_hz / 10.0) ** 2)

    def lateral_gain(self, f_hz: float) -> float:
        """L(f) = L0 / sqrt((1 - (f/fr)^2)^2 + (f/(Q fr))^2) (physics.md effects table)."""
        if self.L0 == 0.0:
            return 0.0
        r = f_hz / self.fr_hz
        return self.L0 / math.sqrt((1.0 - r * r) ** 2 + (r / self.Q) ** 2)


@dataclass
class StationConsts:
    A0_m: float = A0_M
    g_mps2: float = G_MPS2
    latitude_deg: float = LATITUDE_DEG
    earth_rate_radps: float = EARTH_RATE_RADPS
    pulses_per_rev: int = PULSES_PER_REV


@dataclass
class Window:
    """One counter window at indexing position theta, commanded frequency f (0 = static).

    t is window time (0 = the opening pulse edge); start_s is the session time of the opening.
    gamma0_rad is the crank phase at t = 0 (psi = w t + gamma0). eps_radps is the window's
    constant rate error (the instrument repeatability), last_move_s the session time at which
    the indexing head last stopped (for the thermal transient).
    """

    co: Coefficients
    pe: Perturbation
    theta_deg: float
    f_cmd_hz: float
    gamma0_rad: float
    start_s: float
    eps_radps: float = 0.0
    last_move_s: float = -math.inf
    approach_dir: int = 0  # +1 / -1: the indexing head's last move was toward larger / smaller theta
    st: StationConsts = field(default_factory=StationConsts)

    def __post_init__(self) -> None:
        th = math.radians(self.theta_deg)
        self.theta_a = th + self.pe.index_error_rad(th) + self.pe.mount_rad
        self.theta_a += 0.5 * self.pe.backlash_rad * self.approach_dir
        if self.pe.kz_drift_per_s:  # the scale factor of this window: kz at the window's start
            self.co = replace(self.co, kz=self.co.kz * (1.0 + self.pe.kz_drift_per_s * self.start_s))
        self.vib = self.f_cmd_hz > 0.0
        self.f_hz = self.pe.true_freq_hz(self.f_cmd_hz) if self.vib else 0.0
        self.w = 2.0 * math.pi * self.f_hz
        self.T = 1.0 / self.f_hz if self.vib else math.inf
        self.lat = math.radians(self.st.latitude_deg)
        self.lat_gain = self.pe.lateral_gain(self.f_hz) if self.vib else 0.0
        self._kinked = self.co.koq != 0.0 or self.co.kz_asym != 0.0
        self._harmonics()
        if self.vib:
            self._build_profile()
        else:
            self.r_static = float(self.rate_periodic(np.zeros(1))[0])

    # ---- the world: motion, inputs, rate -----------------------------------------------------------
    def psi(self, t: np.ndarray) -> np.ndarray:
        return self.w * t + self.gamma0_rad if self.vib else np.zeros_like(t)

    def z_m(self, t: np.ndarray) -> np.ndarray:
        """z(t) - zbar from physics.md's table motion (static: the crank at rest at psi = 0)."""
        p, pe = self.psi(t), self.pe
        zs1 = pe.z0_m + pe.z1_ms * self.w
        return (
            (self.st.A0_m + zs1) * np.sin(p)
            + pe.zc1_m * np.cos(p)
            + pe.zs2_m * np.sin(2 * p)
            + pe.zc2_m * np.cos(2 * p)
            + pe.zs3_m * np.sin(3 * p)
            + pe.zc3_m * np.cos(3 * p)
        )

    def _harmonics(self) -> None:
        """Non-zero Fourier terms of a_z (m/s^2) and alpha_x (rad) in the crank phase, as (j, sin, cos)."""
        pe, w2 = self.pe, self.w**2
        zs1 = pe.z0_m + pe.z1_ms * self.w
        # a_z = z'': each harmonic j of z contributes -(j w)^2 times itself
        az = [(1, self.st.A0_m + zs1, pe.zc1_m), (2, pe.zs2_m, pe.zc2_m), (3, pe.zs3_m, pe.zc3_m)]
        self._az = [(j, -(j * j) * w2 * s, -(j * j) * w2 * c) for j, s, c in az if s or c] if self.vib else []
        al = [(1, pe.axs1_rad, pe.axc1_rad), (2, pe.ax2s_rad, pe.ax2c_rad)]
        if self.vib:
            self._alpha = [(j, s, c) for j, s, c in al if s or c]
            self._alpha0 = pe.ax0_rad
        else:  # the crank rests at psi = 0: alpha_x = ax0 + axc1 + ax2c
            self._alpha, self._alpha0 = [], pe.ax0_rad + pe.axc1_rad + pe.ax2c_rad
        self._lat_amp = self.lat_gain * self.st.A0_m * w2 / self.st.g_mps2

    def inputs(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """aI, aP, aO (g) and theta_e (rad) at window times t (physics.md, inputs)."""
        t = np.asarray(t, dtype=float)
        p = self.psi(t)
        gz = np.ones_like(t)
        for j, s, c in self._az:
            gz = gz + (s * np.sin(j * p) + c * np.cos(j * p)) / self.st.g_mps2
        th_e = np.full_like(t, self.theta_a + self._alpha0)
        for j, s, c in self._alpha:
            th_e = th_e + s * np.sin(j * p) + c * np.cos(j * p)
        aO = self._lat_amp * np.sin(p + self.pe.phiL_rad) if self._lat_amp else np.zeros_like(t)
        return gz * np.cos(th_e), gz * np.sin(th_e), aO, th_e

    def rate_periodic(self, t: np.ndarray) -> np.ndarray:
        """w_out without the session-time terms (physics.md rate model, plus out-of-library terms)."""
        aI, aP, aO, th_e = self.inputs(t)
        co = self.co
        aI2 = aI * aI
        w = co.k0 + self.eps_radps + aI * (co.kz + aI * (co.kzz + co.k3 * aI + co.k4 * aI2)) + co.ky * aP * aP
        if co.koq:
            w = w + co.koq * aI * np.abs(aI)
        if co.kx:
            w = w + co.kx * aO * aO
        if co.kip:
            w = w + co.kip * aI * aP
        if co.kz_asym:
            w = w + co.kz * co.kz_asym * np.minimum(aI, 0.0)
        return w - self.st.earth_rate_radps * np.sin(self.lat - th_e)

    # ---- session-time terms: rate and exact integral ------------------------------------------------
    def _time_rate(self, t_sess: np.ndarray) -> np.ndarray:
        pe = self.pe
        r = pe.drift_radps_per_s * t_sess + pe.quad_radps_per_s2 * t_sess**2
        if pe.step_radps:
            r = r + pe.step_radps * (t_sess >= pe.step_time_s)
        if pe.transient_radps and math.isfinite(self.last_move_s):
            r = r + pe.transient_radps * np.exp(-(t_sess - self.last_move_s) / pe.transient_tau_s)
        return r

    def _time_antideriv(self, t_sess: np.ndarray) -> np.ndarray:
        pe = self.pe
        a = pe.drift_radps_per_s * t_sess**2 / 2.0 + pe.quad_radps_per_s2 * t_sess**3 / 3.0
        if pe.step_radps:
            a = a + pe.step_radps * np.maximum(t_sess - pe.step_time_s, 0.0)
        if pe.transient_radps and math.isfinite(self.last_move_s):
            tau = pe.transient_tau_s
            a = a - pe.transient_radps * tau * np.exp(-(t_sess - self.last_move_s) / tau)
        return a

    def rate(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return self.rate_periodic(t) + self._time_rate(self.start_s + t)

    def _drift_phi(self, t: np.ndarray) -> np.ndarray:
        return self._time_antideriv(self.start_s + t) - self._time_antideriv(np.array(self.start_s))

    # ---- phi(t) by quadrature -----------------------------------------------------------------------
    def _gl(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Gauss-Legendre integral of the periodic rate over [a, b], element-wise."""
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        half, mid = (b - a) / 2.0, (b + a) / 2.0
        nodes = mid[..., None] + half[..., None] * _X_GL
        return half * (self.rate_periodic(nodes) @ _W_GL)

    def _build_profile(self) -> None:
        T = self.T
        edges = np.linspace(0.0, T, PANELS + 1)
        if self._kinked:  # |aI| and min(aI, 0) have kinks where aI = 0: put panel edges there
            kinks = sign_change_roots(lambda x: self.inputs(x)[0], np.linspace(0.0, T, 4 * _ROOT_GRID + 1))
            edges = np.unique(np.concatenate([edges, kinks]))
        self._edges = edges
        self._cum = np.concatenate([[0.0], np.cumsum(self._gl(edges[:-1], edges[1:]))])
        self.phi_period = float(self._cum[-1])
        # extrema of the periodic profile, for the first-passage period search
        crit = self._zeros(lambda x: self.rate_periodic(x), 0.0, T)
        self._crit = crit
        pts = np.concatenate([[0.0, T], crit])
        prof = self._phi_periodic(pts)
        self._prof_max, self._prof_min = float(prof.max()), float(prof.min())

    def _phi_periodic(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        if not self.vib:
            return self.r_static * t
        k = np.floor(t / self.T)
        tau = t - k * self.T
        j = np.clip(np.searchsorted(self._edges, tau, side="right") - 1, 0, self._edges.size - 2)
        return k * self.phi_period + self._cum[j] + self._gl(self._edges[j], tau)

    def phi(self, t: np.ndarray) -> np.ndarray:
        """Precession angle (rad) at window times t: phi(0) = 0 (physics.md)."""
        t = np.asarray(t, dtype=float)
        return self._phi_periodic(t) + self._drift_phi(t)

    def _zeros(self, f: Callable[[np.ndarray], np.ndarray], a: float, b: float) -> np.ndarray:
        """Zeros of f in [a, b]: sign changes on a grid, each refined by a bracketed root search."""
        return sign_change_roots(f, np.linspace(a, b, _ROOT_GRID + 1))

    # ---- first passage -----------------------------------------------------------------------------
    def mean_rate_sign(self) -> float:
        m = self.phi_period / self.T if self.vib else self.r_static
        m += float(self._time_rate(np.array(self.start_s)))
        if m == 0.0:
            raise ValueError(f"mean rate is zero at theta={self.theta_deg} deg, f={self.f_cmd_hz} Hz")
        return math.copysign(1.0, m)

    def first_passage(self, pulses: int) -> float:
        """Tm: the first t > 0 with |phi(t)| = 2 pi P / 16384 (physics.md), P = pulses > 0."""
        target = pulses * PULSE_RAD
        s = self.mean_rate_sign()

        def g(x: float) -> float:
            return s * float(self.phi(np.array(x))) - target

        if not self.vib:
            hi = target / abs(self.r_static)
            while g(hi) < 0.0:
                hi *= 1.5
            return brentq(g, 0.0, hi, xtol=_XTOL_S, rtol=1e-15, maxiter=200)
        T = self.T
        prof_max = self._prof_max if s > 0 else -self._prof_min

        def period_max(j: int) -> float:  # upper bound of g over period j from its mean trend
            t0 = np.array(j * T)
            return s * float(j * self.phi_period + self._drift_phi(t0)) + prof_max - target

        per = abs(self.phi_period)
        j_hi = max(1, math.ceil((target + abs(self._prof_max) + abs(self._prof_min)) / per) + 2)
        while period_max(j_hi) < 0.0:
            j_hi *= 2
        j = 0 if period_max(0) >= 0.0 else _first_int(period_max, 0, j_hi)
        j = max(j - 2, 0)
        while True:
            a, b = j * T, (j + 1) * T
            pts = np.concatenate([[a], a + self._crit, [b]])
            vals = s * self.phi(pts) - target
            hit = np.nonzero(vals >= 0.0)[0]
            if hit.size:
                m = int(hit[0])
                if m == 0:  # phi at the period's start is already past the target
                    if j == 0:
                        return 0.0
                    raise RuntimeError(f"first passage before period {j}: the period search started too late")
                return brentq(g, pts[m - 1], pts[m], xtol=_XTOL_S, rtol=1e-15, maxiter=200)
            j += 1


def sign_change_roots(f: Callable[[np.ndarray], np.ndarray], grid: np.ndarray) -> np.ndarray:
    """Roots of an element-wise f bracketed by its sign changes on grid, each refined by brentq."""
    v = f(grid)
    idx = np.nonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)[0]
    return np.array([brentq(lambda x: float(f(np.array([x]))[0]), grid[i], grid[i + 1], xtol=_XTOL_S) for i in idx])


def _first_int(f: Callable[[int], float], lo: int, hi: int) -> int:
    """Smallest integer j in (lo, hi] with f(j) >= 0, given f(lo) < 0 <= f(hi) and f increasing."""
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if f(mid) >= 0.0:
            hi = mid
        else:
            lo = mid
    return hi


# ---- reference crossings and stamps -------------------------------------------------------------------
def crossing_time(win: Window, n: np.ndarray) -> np.ndarray:
    """True times of the n-th crank crossing psi = 2 pi n (physics.md: reference at psi = 0 mod 2 pi)."""
    return (2.0 * math.pi * np.asarray(n, dtype=float) - win.gamma0_rad) / win.w


@dataclass
class Stamper:
    """Counter/timer: jitter on each stamped event, then whole ticks of 50 ns of session time.

    jitter(n) returns n jitter values (s). With tick_s = 0 the stamps are exact (noise-free
    signatures). Stamps are returned in ticks (int) or seconds (float) relative to session time 0
    plus the counter's own phase.
    """

    tick_s: float
    jitter: Callable[[int], np.ndarray]
    phase_s: float = 0.0

    def stamp(self, t_sess: np.ndarray) -> np.ndarray:
        t_sess = np.atleast_1d(np.asarray(t_sess, dtype=float))
        x = t_sess + self.jitter(t_sess.size)
        if self.tick_s <= 0.0:
            return x
        return np.floor((x - self.phase_s) / self.tick_s).astype(np.int64)

    def seconds(self, stamps: np.ndarray) -> np.ndarray:
        return stamps * self.tick_s if self.tick_s > 0.0 else stamps


@dataclass
class Timing:
    """What the counter reports for one window (physics.md: Tm, t1, t2, Np), plus the true Tm."""

    Tm_s: float
    t1_s: float | None
    t2_s: float | None
    Np: int | None
    true_Tm_s: float
    open_stamp: float  # stamp of the opening edge, in the stamper's units


def window_timing(win: Window, true_Tm_s: float, stamper: Stamper, extra_s: np.ndarray | None = None) -> Timing:
    """Stamp the opening and closing edges and the reference crossings (with latency) around them.

    extra_s: additional jitter (s) of the first and of the closing reference stamp (heavy tails).
    """
    o1, oc = (0.0, 0.0) if extra_s is None else (float(extra_s[0]), float(extra_s[1]))
    s_open, s_close = stamper.stamp(np.array([win.start_s, win.start_s + true_Tm_s]))
    sec = stamper.seconds
    Tm = float(sec(s_close - s_open))
    if not win.vib:
        return Timing(Tm, None, None, None, true_Tm_s, s_open)
    lat = win.pe.latency_s
    # first crossing stamped after the opening: candidates n with t_n + latency near 0
    n0 = math.floor((win.gamma0_rad - win.w * lat) / (2.0 * math.pi)) - 1
    ns = np.arange(n0, n0 + 5)
    first = stamper.stamp(win.start_s + crossing_time(win, ns) + lat + o1)
    i1 = int(np.nonzero(first > s_open)[0][0])
    n_close0 = math.floor((win.w * (true_Tm_s - lat) + win.gamma0_rad) / (2.0 * math.pi)) - 1
    nc = np.arange(n_close0, n_close0 + 5)
    close = stamper.stamp(win.start_s + crossing_time(win, nc) + lat + oc)
    ic = int(np.nonzero(close >= s_close)[0][0])
    t1 = float(sec(first[i1] - s_open))
    t2 = float(sec(close[ic] - s_close))
    return Timing(Tm, t1, t2, int(nc[ic] - ns[i1]), true_Tm_s, s_open)


# ---- raw records ---------------------------------------------------------------------------------------
def pulse_edges(win: Window, t_a: float, t_b: float) -> tuple[np.ndarray, np.ndarray]:
    """Every pulse edge in (t_a, t_b]: times where phi crosses k 2 pi/16384, with direction +1/-1.

    phi is monotone between consecutive zeros of w_out; cells of T/512 (static: 1 ms) with those
    zeros inserted are monotone, so the levels each cell crosses are known from its end values,
    and each edge is solved on its cell by a bracketed (safeguarded) Newton iteration.
    """
    step = win.T / _ROOT_GRID if win.vib else 1e-3
    n = max(2, math.ceil((t_b - t_a) / step) + 1)
    grid = np.linspace(t_a, t_b, n)
    grid = np.unique(np.concatenate([grid, sign_change_roots(win.rate, grid)]))
    lev = win.phi(grid) / PULSE_RAD
    lo_lev, hi_lev = np.minimum(lev[:-1], lev[1:]), np.maximum(lev[:-1], lev[1:])
    up = lev[1:] > lev[:-1]
    # levels k crossed in cell i: up cells (lev_a, lev_b], down cells [lev_b, lev_a)
    k_first = np.where(up, np.floor(lo_lev) + 1, np.ceil(lo_lev))
    k_last = np.where(up, np.floor(hi_lev), np.ceil(hi_lev) - 1)
    count = np.maximum(k_last - k_first + 1, 0).astype(np.int64)
    cell = np.repeat(np.arange(count.size), count)
    offs = np.arange(cell.size) - np.repeat(np.cumsum(count) - count, count)
    upc = up[cell]
    k = np.where(upc, k_first[cell] + offs, k_last[cell] - offs)  # in time order within the cell
    level = k * PULSE_RAD
    sgn = np.where(upc, 1.0, -1.0)
    res = elementwise.find_root(
        lambda x, lv: win.phi(x) - lv,
        (grid[cell], grid[cell + 1]),
        args=(level,),
        tolerances={"xatol": _XTOL_S, "xrtol": 2e-16},
    )
    x = np.asarray(res.x, dtype=float)
    bad = ~np.isfinite(x)
    if np.any(bad):  # a level met at a cell end to rounding (no sign change left): the nearer end
        lo, hi = grid[cell][bad], grid[cell + 1][bad]
        near_lo = np.abs(win.phi(lo) - level[bad]) <= np.abs(win.phi(hi) - level[bad])
        x[bad] = np.where(near_lo, lo, hi)
    return x, sgn.astype(np.int8)


def grating_samples(win: Window, t_a: float, t_b: float, zbar_m: float, noise_m: float, rng: np.random.Generator):
    """5 kHz absolute-grating samples in [t_a, t_b]: z(t) of physics.md plus white noise, 1 nm steps."""
    dt = 1.0 / GRATING_HZ
    first = math.ceil((win.start_s + t_a) / dt) * dt - win.start_s  # the head samples on its own grid
    t = first + dt * np.arange(math.floor((t_b - first) / dt) + 1)
    z = zbar_m + win.z_m(t) + rng.normal(0.0, noise_m, t.size)
    return t, np.round(z / GRATING_LSB_M) * GRATING_LSB_M
