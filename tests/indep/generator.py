"""Designs, instruments, noise and whole sessions, written as piga-session/1 directories (physics.md).

Window length rule. Every vibration window asks for P = `window_revs` revolutions (16384 pulses
each). A window whose nominal rate (the instrument without effects, period mean) would need more
than the design's `max_window_s` (drawn 600-3600 s) gets fewer pulses: P = floor(|w| max_window_s /
(2 pi / 16384)); a static window keeps at least 16 pulses and a vibration window at least 256
(the first passage must stay far above the +-0.1 rad swing of phi); a point that cannot reach its
minimum within max_window_s is left out of the design. Static windows near a horizontal input axis
(theta near 90 or 270 deg, hours long at full P) are therefore bounded by max_window_s, and
generation time does not depend on window length (phi is solved period by period).

Noise: each window has a constant rate error eps ~ N(0, sigma) ("per_window": the instrument
repeatability of physics.md, stated in session.json unless state_noise is off) or N(0, sigma sqrt(300 s / Tm))
("white": a white rate noise that averages down, never stated as a repeatability) or both, half the variance
each at 300 s ("mixed": never stated); every stamped event has
Gaussian jitter timing_sigma_s and is counted in 50 ns ticks; grating samples carry white noise
noise_m and 1 nm steps.
"""

from __future__ import annotations

import copy
import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from indep.world import (
    A0_M,
    EARTH_RATE_RADPS,
    G_MPS2,
    GRATING_HZ,
    LATITUDE_DEG,
    PULSE_RAD,
    PULSES_PER_REV,
    TICK_S,
    Coefficients,
    Perturbation,
    Stamper,
    Window,
    crossing_time,
    grating_samples,
    pulse_edges,
    window_timing,
)

FAMILIES = ("equal_angle", "equal_accel", "unequal", "seed000")
SEED000 = {"k0": 1.5e-4, "kz": 0.56, "kzz": 6.0e-6, "ky": 5.0e-6, "k3": 7e-7}
MIN_STATIC_PULSES = 16
MIN_VIBRATION_PULSES = 256
WHITE_REF_S = 300.0


@dataclass(frozen=True)
class PointSpec:
    """One window of the design: position, commanded frequency (0 = static)."""

    position_deg: float
    freq_hz: float


@dataclass(frozen=True)
class Design:
    """A session design: what is measured, in which order, with which windows and settle times."""

    family: str
    positions_deg: tuple[float, ...]  # distinct positions, in visiting order
    freqs_hz: tuple[float, ...]
    window_revs: int  # P per vibration point, revolutions
    static_repeats: int  # static windows per position
    order: str  # "ascending" or "shuffled"
    points: tuple[PointSpec, ...]  # every window in visiting order
    max_window_s: float = 3600.0
    index_move_s: float = 20.0
    settle_index_s: float = 30.0
    settle_freq_s: float = 15.0
    window_s: float | None = None  # equal windows: every window's nominal Tm (pulses from its rate), not P revs

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"family={self.family!r}: allowed {FAMILIES}")
        if not 1 <= self.window_revs <= 1000:
            raise ValueError(f"window_revs={self.window_revs}: allowed 1..1000 revolutions")
        if self.max_window_s <= 0:
            raise ValueError(f"max_window_s={self.max_window_s}: must be > 0 s")
        for p in self.points:
            if p.freq_hz < 0 or p.freq_hz > 10.0:
                raise ValueError(f"freq_hz={p.freq_hz}: allowed 0 (static) or (0, 10] Hz")


def _positions(rng: np.random.Generator, family: str, n: int) -> list[float]:
    if family == "seed000":
        return [36.0 * k for k in range(10)]
    if family == "equal_angle":
        off = float(rng.choice([0.0, rng.uniform(0.0, 360.0 / n)]))
        return [round((off + 360.0 * k / n) % 360.0, 6) for k in range(n)]
    if family == "equal_accel":  # equal steps in cos theta from +1 to -1, either side of the circle
        cos_t = np.linspace(1.0, -1.0, n)
        th = np.degrees(np.arccos(cos_t))
        side = rng.random(n) < 0.5
        return [round(float(360.0 - t if s and 0 < t < 180 else t), 6) for t, s in zip(th, side, strict=True)]
    # unequal: random angles at least 4 deg apart
    while True:
        th = np.sort(rng.uniform(0.0, 360.0, n))
        gaps = np.diff(np.concatenate([th, [th[0] + 360.0]]))
        if gaps.min() >= 4.0:
            return [round(float(t), 4) for t in th]


def _freqs(rng: np.random.Generator, family: str) -> list[float]:
    if family == "seed000":
        return [8.0, 9.0, 10.0]
    n = int(rng.integers(2, 10))
    while True:
        ints = rng.integers(1, 11, n)
        frac = rng.choice([0.0, 0.25, 0.5, 0.75, 0.35, 0.1], n)
        f = np.clip(np.round(ints + np.where(rng.random(n) < 0.5, frac, 0.0), 2), 1.0, 10.0)
        f = np.unique(f)
        if f.size == n and np.any(f != np.round(f)):
            return [float(x) for x in f]


def random_design(rng: np.random.Generator, family: str) -> Design:
    """A random design of the family: 6-16 positions, 2-9 frequencies in 1-10 Hz, 10-50 revolutions."""
    if family not in FAMILIES:
        raise ValueError(f"family={family!r}: allowed {FAMILIES}")
    n_pos = 10 if family == "seed000" else int(rng.integers(6, 17))
    positions = _positions(rng, family, n_pos)
    freqs = _freqs(rng, family)
    revs = 50 if family == "seed000" else int(rng.integers(10, 51))
    repeats = int(rng.integers(1, 4))
    order = "ascending" if family == "seed000" and rng.random() < 0.5 else str(rng.choice(["ascending", "shuffled"]))
    visit = list(positions) if order == "ascending" else [positions[i] for i in rng.permutation(n_pos)]
    points: list[PointSpec] = []
    for th in visit:
        fs = list(freqs) if order == "ascending" else [freqs[i] for i in rng.permutation(len(freqs))]
        points.append(PointSpec(th, 0.0))
        points.extend(PointSpec(th, f) for f in fs)
    for _r in range(1, repeats):  # repeated statics: later passes over the positions
        again = visit if order == "ascending" else [visit[i] for i in rng.permutation(n_pos)]
        points.extend(PointSpec(th, 0.0) for th in again)
    return Design(
        family=family,
        positions_deg=tuple(visit),
        freqs_hz=tuple(freqs),
        window_revs=revs,
        static_repeats=repeats,
        order=order,
        points=tuple(points),
        max_window_s=float(rng.uniform(600.0, 3600.0)),
        index_move_s=float(rng.uniform(10.0, 40.0)),
        settle_index_s=float(rng.uniform(20.0, 120.0)),
        settle_freq_s=float(rng.uniform(10.0, 60.0)),
    )


def equal_angle_design(
    n_positions: int,
    freqs_hz: tuple[float, ...],
    *,
    window_revs: int = 20,
    static_repeats: int = 1,
    max_window_s: float = 3600.0,
    window_s: float | None = None,
) -> Design:
    """A fixed equal-angle design of any size (n_positions x (static_repeats + len(freqs)) windows),
    for sessions larger than random_design draws (e.g. 160 or 640 points)."""
    if n_positions < 1:
        raise ValueError(f"n_positions={n_positions}: must be >= 1")
    positions = tuple(round(360.0 * k / n_positions, 9) for k in range(n_positions))
    points = [PointSpec(th, f) for th in positions for f in (0.0, *freqs_hz)]
    points += [PointSpec(th, 0.0) for _ in range(1, static_repeats) for th in positions]
    return Design(
        "equal_angle",
        positions,
        tuple(freqs_hz),
        window_revs,
        static_repeats,
        "ascending",
        tuple(points),
        max_window_s=max_window_s,
        window_s=window_s,
    )


@dataclass
class Noise:
    """Noise of the recording (see the module docstring)."""

    rate_sigma_radps: float
    rate_form: str  # "per_window" | "white" | "mixed"
    timing_sigma_s: float
    grating_noise_m: float
    tick_s: float = TICK_S

    def rate_sd(self, tm_nominal_s: float) -> float:
        if self.rate_form == "white":
            return self.rate_sigma_radps * math.sqrt(WHITE_REF_S / tm_nominal_s)
        if self.rate_form == "mixed":
            return self.rate_sigma_radps * math.sqrt(0.5 + 0.5 * WHITE_REF_S / tm_nominal_s)
        return self.rate_sigma_radps

    def identity_sd(self) -> float:
        """sd of t1 + Np T - Tm - t2 = R1 - Rc + Np T: two stamps, jitter plus tick rounding."""
        return math.sqrt(2.0 * (self.timing_sigma_s**2 + self.tick_s**2 / 12.0))

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Truth:
    """The world of one session: instrument, perturbations, noise, and out-of-library extras."""

    co: Coefficients
    pe: Perturbation = field(default_factory=Perturbation)
    noise: Noise | None = None
    miscount: dict[int, int] = field(default_factory=dict)  # point index -> +-1 pulses (out of library)
    jitter_outliers_s: np.ndarray | None = None  # (n_points, 2): extra jitter of the two reference stamps

    def with_(self, co: Coefficients | None = None, pe: Perturbation | None = None) -> Truth:
        t = copy.copy(self)
        t.co, t.pe = co or self.co, pe or self.pe
        return t


def _far(rng: np.random.Generator, lo: float, hi: float, seed_value: float | None, signed: bool) -> float:
    """|x| log-uniform in [lo, hi] (sign random when signed), at least 30 % away from seed 000's value."""
    while True:
        x = math.exp(rng.uniform(math.log(lo), math.log(hi)))
        if signed and rng.random() < 0.5:
            x = -x
        if seed_value is None or abs(x / seed_value - 1.0) > 0.3:
            return x


def random_coefficients(rng: np.random.Generator) -> Coefficients:
    """Instrument coefficients drawn far from seed 000's (kz 0.3-0.9 rad/s/g, others of both signs)."""
    return Coefficients(
        k0=_far(rng, 5e-5, 5e-4, SEED000["k0"], True),
        kz=_far(rng, 0.3, 0.9, SEED000["kz"], False),
        kzz=_far(rng, 1e-6, 3e-5, SEED000["kzz"], True),
        ky=_far(rng, 1e-6, 3e-5, SEED000["ky"], True),
        k3=_far(rng, 1e-7, 5e-6, SEED000["k3"], True),
    )


def random_noise(rng: np.random.Generator) -> Noise:
    """Rate noise 2e-7..5e-6 rad/s, timing noise 5e-8..2e-7 s, grating noise 2e-8..5e-7 m (log-uniform)."""

    def lu(lo: float, hi: float) -> float:
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))

    return Noise(
        rate_sigma_radps=lu(2e-7, 5e-6),
        rate_form="white" if rng.random() < 0.3 else "per_window",
        timing_sigma_s=lu(5e-8, 2e-7),
        grating_noise_m=lu(2e-8, 5e-7),
    )


def nominal_rate(co: Coefficients, theta_deg: float, f_hz: float) -> float:
    """Mean rate of the instrument without effects (period mean), for the window-length rule."""
    w = Window(co, Perturbation(), theta_deg, f_hz, 0.0, 0.0)
    return w.phi_period / w.T if w.vib else w.r_static


def plan_pulses(design: Design, co: Coefficients) -> list[tuple[PointSpec, int, float]]:
    """(point, pulses, nominal Tm) for every window kept by the window-length rule (module docstring)."""
    out = []
    for p in design.points:
        r = abs(nominal_rate(co, p.position_deg, p.freq_hz))
        full = design.window_revs * PULSES_PER_REV if design.window_s is None else int(r * design.window_s / PULSE_RAD)
        cap = math.floor(r * design.max_window_s / PULSE_RAD)
        pulses = min(full, cap)
        if pulses < (MIN_VIBRATION_PULSES if p.freq_hz else MIN_STATIC_PULSES):
            continue
        out.append((p, pulses, pulses * PULSE_RAD / r))
    return out


@dataclass
class Draws:
    """Random numbers of a session drawn once, so noise-free and noisy runs share phases and waits."""

    gamma0_rad: np.ndarray
    wait_s: np.ndarray
    eps_unit: np.ndarray
    raw_points: list[int]
    raw_u: np.ndarray  # where each raw stretch starts (fraction) or -1: at the window's end
    raw_len_s: float
    zbar_m: float
    counter_phase_s: float


def draw_session(rng: np.random.Generator, n: int, raw: bool, plan: list) -> Draws:
    vib = [i for i, (p, _, _) in enumerate(plan) if p.freq_hz]
    stat = [i for i, (p, _, _) in enumerate(plan) if not p.freq_hz]
    raw_points: list[int] = []
    if raw:
        raw_points = sorted(
            [int(i) for i in rng.choice(vib, size=min(3, len(vib)), replace=False)]
            + [int(i) for i in rng.choice(stat, size=min(1, len(stat)), replace=False)]
        )
    u = np.where(rng.random(len(raw_points)) < 0.3, -1.0, rng.random(len(raw_points)))
    return Draws(
        gamma0_rad=rng.uniform(0.0, 2.0 * math.pi, n),
        wait_s=rng.uniform(0.0, 1.0, n),
        eps_unit=rng.standard_normal(n),
        raw_points=raw_points,
        raw_u=u,
        raw_len_s=float(rng.uniform(1.0, 3.0)),
        zbar_m=float(rng.uniform(0.05, 0.15)),
        counter_phase_s=float(rng.uniform(0.0, TICK_S)),
    )


@dataclass
class Row:
    """One points.csv row plus what the signatures need (noise-free: exact t1, t2)."""

    point_id: str
    sequence: int
    start_s: float
    position_deg: float
    freq_hz: float
    pulses: int
    Tm_s: float
    t1_s: float | None
    t2_s: float | None
    Np: int | None
    true_Tm_s: float
    sd_rate: float
    window: Window
    open_stamp: float = 0.0  # the counter's stamp of the opening edge (ticks, or s when noise-free)


def simulate(
    design: Design,
    truth: Truth,
    draws: Draws,
    plan: list,
    noise_rng: np.random.Generator | None = None,
) -> list[Row]:
    """Run the session in visiting order; noise_rng None = noise-free (no eps, jitter or ticks)."""
    noise = truth.noise
    noisy = noise_rng is not None and noise is not None
    if noisy:
        assert noise_rng is not None and noise is not None
        sigma_t, rng_t = noise.timing_sigma_s, noise_rng
        stamper = Stamper(noise.tick_s, lambda k: rng_t.normal(0.0, sigma_t, k), draws.counter_phase_s)
    else:
        stamper = Stamper(0.0, lambda k: np.zeros(k))
    rows: list[Row] = []
    t, pos, freq, last_move, approach = 0.0, None, None, -math.inf, 1
    for i, (p, pulses, tm_nom) in enumerate(plan):
        if p.position_deg != pos:
            if pos is not None:
                approach = 1 if p.position_deg > pos else -1
            t += design.index_move_s
            last_move, pos, freq = t, p.position_deg, None
            t += design.settle_index_s
        if p.freq_hz != freq:
            t += design.settle_freq_s
            freq = p.freq_hz
        t += float(draws.wait_s[i])
        sd = noise.rate_sd(tm_nom) if noise else 0.0
        eps = sd * float(draws.eps_unit[i]) if noisy else 0.0
        gamma0 = float(draws.gamma0_rad[i])
        win = Window(truth.co, truth.pe, p.position_deg, p.freq_hz, gamma0, t, eps, last_move, approach)
        sign = win.mean_rate_sign()
        true_tm = win.first_passage(pulses + truth.miscount.get(i, 0))
        extra = None if truth.jitter_outliers_s is None else truth.jitter_outliers_s[i]
        tim = window_timing(win, true_tm, stamper, extra)
        if not tim.Tm_s > 0.0:
            raise ValueError(f"window {i} ({p.position_deg} deg, {p.freq_hz} Hz): Tm = {tim.Tm_s} s, too strong")
        rows.append(
            Row(
                f"p{i:03d}",
                i,
                t,
                p.position_deg,
                p.freq_hz,
                int(sign * pulses),
                tim.Tm_s,
                tim.t1_s,
                tim.t2_s,
                tim.Np,
                true_tm,
                sd,
                win,
                float(tim.open_stamp),
            )
        )
        t += true_tm + 0.5
    return rows


def raw_record(row: Row, draws: Draws, k: int, truth: Truth, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The k-th raw stretch: grating samples, stamped pulse edges with direction, reference stamps."""
    win, noise = row.window, truth.noise
    assert noise is not None
    length = min(draws.raw_len_s, row.true_Tm_s)
    u = float(draws.raw_u[k])
    t_a = row.true_Tm_s - length if u < 0 else u * (row.true_Tm_s - length)
    t_b = t_a + length
    gt, gz = grating_samples(win, t_a, t_b, draws.zbar_m, noise.grating_noise_m, rng)
    edges, dirs = pulse_edges(win, t_a, t_b)
    st = Stamper(noise.tick_s, lambda n: rng.normal(0.0, noise.timing_sigma_s, n), draws.counter_phase_s)
    open_tick = int(row.open_stamp)  # the same opening stamp as Tm, t1 and t2
    e_ticks = st.stamp(win.start_s + edges)
    order = np.argsort(e_ticks, kind="stable")  # the counter reports edges in arrival order
    out = {
        "grating_t": gt,
        "grating_z": gz,
        "pulse_t": (e_ticks[order] - open_tick) * noise.tick_s,
        "pulse_dir": dirs[order],
    }
    if win.vib:
        lat = win.pe.latency_s
        n_a = math.ceil((win.w * (t_a - lat) + win.gamma0_rad) / (2 * math.pi))
        n_b = math.floor((win.w * (t_b - lat) + win.gamma0_rad) / (2 * math.pi))
        ref = crossing_time(win, np.arange(n_a, n_b + 1)) + lat
        out["reference_t"] = np.sort((st.stamp(win.start_s + ref) - open_tick) * noise.tick_s)
    else:
        out["reference_t"] = np.empty(0)
    return out


def _fmt(x: float | int | None) -> str:
    if x is None:
        return ""
    return str(x) if isinstance(x, int) else repr(float(x))


def write_session(
    out_dir: str | os.PathLike,
    design: Design,
    truth: Truth,
    rng: np.random.Generator,
    raw: bool = False,
    state_noise: bool = True,
    *,
    draws: Draws | None = None,
    plan: list | None = None,
    notes: str = "independent generator (tests/indep)",
    raw_optional: tuple[bool, bool] = (True, True),
) -> list[Row]:
    """Simulate a noisy session and write it as a piga-session/1 directory; return its rows.

    rng drives the session's random draws (unless draws is given) and all noise. raw_optional says
    whether the optional arrays pulse_dir and reference_t are written.
    """
    if truth.noise is None:
        raise ValueError("truth.noise: a written session needs a noise model")
    plan = plan if plan is not None else plan_pulses(design, truth.co)
    draws = draws if draws is not None else draw_session(rng, len(plan), raw, plan)
    rows = simulate(design, truth, draws, plan, noise_rng=rng)
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".indep-", dir=out.parent))  # same file system: the rename is atomic
    try:
        meta: dict = {
            "format": "piga-session/1",
            "station": {
                "A0_m": A0_M,
                "latitude_deg": LATITUDE_DEG,
                "g_mps2": G_MPS2,
                "earth_rate_radps": EARTH_RATE_RADPS,
                "pulses_per_rev": PULSES_PER_REV,
            },
            "notes": notes,
            "generator": "tests/indep",
        }
        if state_noise:
            n = truth.noise
            if n.rate_form == "per_window":
                meta["instrument_repeatability_radps"] = n.rate_sigma_radps
            meta["timing"] = {"timer_resolution_s": n.tick_s, "timing_sigma_s": n.timing_sigma_s}
            if raw:
                meta["grating"] = {"rate_hz": GRATING_HZ, "noise_m": n.grating_noise_m}
            meta["settling_s"] = design.settle_index_s
        (tmp / "session.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
        header = "point_id,sequence,start_s,position_deg,freq_hz,kind,pulses,Tm_s,t1_s,t2_s,Np"
        lines = [header]
        for r in rows:
            vals = [r.point_id, str(r.sequence), _fmt(r.start_s), _fmt(r.position_deg), _fmt(r.freq_hz)]
            vals += ["vibration" if r.freq_hz else "static", str(r.pulses), _fmt(r.Tm_s)]
            vals += [_fmt(r.t1_s), _fmt(r.t2_s), _fmt(r.Np)]
            lines.append(",".join(vals))
        (tmp / "points.csv").write_text("\n".join(lines) + "\n")
        if raw and draws.raw_points:
            (tmp / "raw").mkdir()
            for k, i in enumerate(draws.raw_points):
                rec = raw_record(rows[i], draws, k, truth, rng)
                if not raw_optional[0]:
                    rec.pop("pulse_dir")
                if not raw_optional[1]:
                    rec.pop("reference_t")
                _save_npz(tmp / "raw" / f"{rows[i].point_id}.npz", rec)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    return rows


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez with a fixed member timestamp, so the same session is the same file bit for bit."""
    import zipfile

    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as zf:
        for name in sorted(arrays):
            info = zipfile.ZipInfo(name + ".npy", date_time=(2000, 1, 1, 0, 0, 0))
            with zf.open(info, "w") as fh:
                np.lib.format.write_array(fh, np.asarray(arrays[name]), allow_pickle=False)
