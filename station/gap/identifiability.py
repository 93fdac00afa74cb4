"""Identifiability of each candidate in the session's design, before any ranking.

For every candidate parameter, its whitened column J_p (station.gap.fit.Linearisation)
is projected onto the orthogonal complement of the calibrated terms' columns
(static levels and kz, kzz, ky, k3): r_p = P_perp J_p. Then
- rho = |r_p| / |J_p'| is the fraction of its signature that the calibrated
  coefficients do not absorb (J_p' = J_p without its per-position constant,
  which the static levels always absorb); rho < ABSORBED_RHO: "absorbed" (the parameter
  is not fitted, it stays at the twin's value);
- |r_p| * scale is the signal-to-noise ratio after projection of an effect of
  typical size, and 3 / |r_p| the smallest value detectable at 3 sigma;
- within a candidate, parameters are kept by pivoted QR of their projected
  columns; one that keeps < ABSORBED_RHO of its norm after its siblings is
  "degenerate" (not separable from them);
- between candidates, the canonical correlations of the projected column
  spaces (cosines of the principal angles); >= COLLINEAR_COS: "collinear".
For each parameter that is absorbed, degenerate or collinear, extra test
points are tried (other frequencies, extra positions, a second crank
amplitude, short low-frequency windows) by appending simulated points of
the twin to the design and recomputing the same numbers; raw streams are
judged from what the grating and pulse records measure directly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg

from station.gap import candidates as cl
from station.gap.design import PointDesign
from station.gap.fit import Channels, Linearisation, linear_design, model_columns
from station.gap.forward import predict
from station.gap.noise import rate_weights
from station.session import Session
from station.twin.config import NoiseModel, TwinConfig
from station.twin.measurement import PointSpec, simulate_point

ABSORBED_RHO = 0.01
COLLINEAR_COS = 0.95
DETECT_SIGMA = 3.0

# What a raw stream measures directly (physics.md, piga-session/1 raw/<point_id>.npz).
RAW_MEASURES = {
    "waveform_fundamental.z0": "the grating measures Zs1 at each frequency directly",
    "waveform_fundamental.z1": "the grating measures Zs1 at each frequency directly",
    "waveform_fundamental.Zc1": "the grating measures the fundamental's phase, but only relative to the "
    "reference mark, so it cannot tell Zc1 from read-head latency either",
    "waveform_harmonics.Zs2": "the grating measures the harmonics directly",
    "waveform_harmonics.Zc2": "the grating measures the harmonics directly",
    "waveform_harmonics.Zs3": "the grating measures the harmonics directly",
    "waveform_harmonics.Zc3": "the grating measures the harmonics directly",
    "frequency_error.eps_f": "the grating and reference marks give the true frequency directly",
    "readhead_latency.delta": "grating and reference marks see latency as a phase, like Zc1; "
    "a second reference (or frequencies far apart) separates them",
}


@dataclass
class ParamId:
    key: str
    unit: str
    scale: float
    rho: float  # fraction not absorbed by the calibrated terms
    snr_at_scale: float  # after projection, for an effect of typical size
    min_detectable: float  # 3-sigma, parameter units
    status: str  # identifiable | weak | absorbed | degenerate | no_signature
    collinear_with: list[tuple[str, float]] = field(default_factory=list)
    separating: list[dict] = field(default_factory=list)

    def to_json(self) -> dict:
        return {
            "parameter": self.key,
            "unit": self.unit,
            "typical_magnitude": self.scale,
            "fraction_not_absorbed": _finite(self.rho),
            "snr_after_projection_at_typical_magnitude": _finite(self.snr_at_scale),
            "min_detectable_3sigma": _finite(self.min_detectable),
            "status": self.status,
            "collinear_with": [{"candidate": n, "cos": round(c, 4)} for n, c in self.collinear_with],
            "separating_test_points": self.separating,
        }


@dataclass
class CandidateId:
    name: str
    params: list[ParamId]
    kept: list[str]  # parameter keys that are fitted
    collinear_with: list[tuple[str, float]]
    identifiable: bool
    reason: str

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "identifiable": self.identifiable,
            "reason": self.reason,
            "fitted_parameters": self.kept,
            "collinear_with": [{"candidate": n, "cos": round(c, 4)} for n, c in self.collinear_with],
            "parameters": [p.to_json() for p in self.params],
        }


@dataclass
class IdentifiabilityReport:
    candidates: dict[str, CandidateId]
    noise_ratio: float  # whitening sigma / honest sigma (scales the SNR numbers)

    @property
    def dropped(self) -> frozenset[str]:
        kept = {k for c in self.candidates.values() for k in c.kept}
        return frozenset(p.key for c in self.candidates.values() for p in c.params if p.key not in kept)

    def fittable(self) -> list[str]:
        return [n for n, c in self.candidates.items() if c.kept]

    def to_json(self) -> dict:
        return {
            "method": "columns of each parameter projected off the calibrated terms (static levels, kz, kzz, "
            f"ky, k3); absorbed if the fraction kept < {ABSORBED_RHO}; collinear if the cosine of the "
            f"principal angle between two candidates' projected columns >= {COLLINEAR_COS}",
            "candidates": [c.to_json() for c in self.candidates.values()],
        }


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _subspace(cols: np.ndarray) -> np.ndarray:
    if cols.shape[1] == 0:
        return cols
    U, s, _ = np.linalg.svd(cols, full_matrices=False)
    return U[:, s > 1e-9 * s.max()] if s.size and s.max() > 0 else U[:, :0]


def _cos(A: np.ndarray, B: np.ndarray) -> float:
    if A.shape[1] == 0 or B.shape[1] == 0:
        return 0.0
    return float(np.linalg.svd(A.T @ B, compute_uv=False).max())


def assess(lin: Linearisation, noise_ratio: float = 1.0, suggest: bool = True) -> IdentifiabilityReport:
    """Absorbed / degenerate / collinear status of every candidate and parameter of the library."""
    proj = {k: lin.project(c[:, None])[:, 0] for k, c in lin.columns.items()}
    out: dict[str, CandidateId] = {}
    spaces: dict[str, np.ndarray] = {}
    for name, cand in lin.cands.items():
        params, kept = [], []
        for fp in cand.free:
            col = lin.columns[fp.key][:, None]
            raw, pr = float(np.linalg.norm(lin.project_levels(col))), float(np.linalg.norm(proj[fp.key]))
            rho = pr / raw if raw > 0 else math.nan
            status = "no_signature" if raw == 0 else ("absorbed" if rho < ABSORBED_RHO else "identifiable")
            snr = pr * fp.scale * noise_ratio
            if status == "identifiable" and snr < 1.0:
                status = "weak"
            mdm = DETECT_SIGMA / (pr * noise_ratio) if pr > 0 else math.inf
            params.append(ParamId(fp.key, fp.unit, fp.scale, rho, snr, mdm, status))
        live = [p for p in params if p.status in ("identifiable", "weak")]
        if live:
            M = np.column_stack([proj[p.key] / np.linalg.norm(proj[p.key]) for p in live])
            _, R, piv = scipy.linalg.qr(M, mode="economic", pivoting=True)
            diag = np.abs(np.diag(R))
            for rank_pos, j in enumerate(piv):
                if diag[rank_pos] < ABSORBED_RHO:
                    live[j].status = "degenerate"
                else:
                    kept.append(live[j].key)
        kept = [p.key for p in params if p.key in kept]  # table order
        spaces[name] = (
            _subspace(np.column_stack([proj[k] for k in kept])) if kept else np.zeros((proj[cand.free[0].key].size, 0))
        )
        out[name] = CandidateId(name, params, kept, [], bool(kept), "")
    for name, cid in out.items():
        cos = [(other, _cos(spaces[name], spaces[o2])) for other, o2 in ((n, n) for n in out) if other != name]
        cid.collinear_with = sorted([(n, c) for n, c in cos if c >= COLLINEAR_COS], key=lambda x: -x[1])
        for p in cid.params:
            if p.key in cid.kept:
                v = proj[p.key] / np.linalg.norm(proj[p.key])
                p.collinear_with = sorted(
                    [
                        (n, float(np.linalg.norm(spaces[n].T @ v)))
                        for n in out
                        if n != name and spaces[n].shape[1] and np.linalg.norm(spaces[n].T @ v) >= COLLINEAR_COS
                    ],
                    key=lambda x: -x[1],
                )
        if not cid.kept:
            cid.identifiable = False
            cid.reason = "every parameter is absorbed by the calibrated coefficients or leaves no signature"
        elif cid.collinear_with:
            cid.identifiable = False
            cid.reason = "nearly collinear with " + ", ".join(f"{n} (cos {c:.3f})" for n, c in cid.collinear_with)
        else:
            weak = [p.key for p in cid.params if p.status == "weak"]
            cid.reason = "identifiable" + (
                f"; an effect of typical size is below the noise for {', '.join(weak)}" if weak else ""
            )
    report = IdentifiabilityReport(out, noise_ratio)
    if suggest:
        _suggest(lin, report)
    return report


# ----------------------------------------------------------------------------- separating test points


@dataclass(frozen=True)
class _Option:
    label: str
    specs: tuple[PointSpec, ...]
    A0_factor: float = 1.0


def _options(design: PointDesign, pulses_per_rev: int) -> list[_Option]:
    """Extra test points to try: each is a set of points added to the recorded design."""
    pos = [float(p) for p in design.positions_deg]
    freqs = sorted({float(f) for f in design.freq_hz[design.vib]})
    preset = {p: _preset_for(design, p, pulses_per_rev) for p in pos}
    opts: list[_Option] = []
    for f in (2.0, 4.0, 6.0):
        if all(abs(f - g) > 0.5 for g in freqs):
            opts.append(_Option(f"add {f:g} Hz at every position", tuple(PointSpec(p, f, preset[p]) for p in pos)))
    low = [f for f in (2.0, 4.0) if all(abs(f - g) > 0.5 for g in freqs)]
    if low:
        opts.append(
            _Option(
                f"add {low[0]:g} Hz with short windows (1 precession revolution) at every position",
                tuple(PointSpec(p, low[0], pulses_per_rev) for p in pos),
            )
        )
    if len(pos) >= 2:
        step = float(np.min(np.diff(sorted(pos)))) if len(pos) > 1 else 36.0
        new = [p + step / 2 for p in pos if abs(math.cos(math.radians(p + step / 2))) > 0.2]
        specs = []
        for p in new:
            pp = _preset_for(design, p, pulses_per_rev)
            specs += [PointSpec(p, f, pp) for f in freqs] + [PointSpec(p, 0.0, pp)]
        opts.append(_Option(f"add {len(new)} positions half-way between the recorded ones", tuple(specs)))
    if freqs:
        opts.append(
            _Option(
                "repeat the vibration points with a second crank amplitude A0/2",
                tuple(PointSpec(p, f, preset[p]) for p in pos for f in freqs),
                A0_factor=0.5,
            )
        )
    return opts


def _preset_for(design: PointDesign, position_deg: float, pulses_per_rev: int) -> int:
    """Whole revolutions giving about the session's median window at this position."""
    tm = float(np.median(design.Tm_s))
    cos = np.abs(np.cos(design.theta_rad))
    ok = cos > 0.3
    gain = float(np.median(np.abs(design.rate_radps[ok]) / cos[ok])) if ok.any() else 0.56
    r = max(abs(gain * math.cos(math.radians(position_deg))), 1.5e-4)
    return int(max(1, round(r * tm / (2 * math.pi))) * pulses_per_rev)


def _hypothetical(design: PointDesign, twin: TwinConfig, specs: Sequence[PointSpec], seed: int = 7) -> PointDesign:
    """Records the twin would give for `specs` (noise-free), as a design."""
    quiet = replace(
        twin, noise=NoiseModel(rate_noise_ref_s=twin.noise.rate_noise_ref_s, timer_tick_s=twin.noise.timer_tick_s)
    )
    rng = np.random.default_rng(seed)
    t0 = float(design.start_s.max() + design.Tm_s.max()) + 60.0
    recs = []
    for i, spec in enumerate(specs):
        sp = simulate_point(spec, quiet, rng, start_s=t0, point_id=f"X{i}", sequence=10_000 + i)
        recs.append(sp.record)
        t0 += sp.true_Tm_s + 60.0
    return PointDesign.from_session(Session(_station(twin), recs))


def _station(twin: TwinConfig):
    from station.twin.session_sim import station_info

    return station_info(twin)


def _columns_for(ch_design: PointDesign, twin: TwinConfig, lin: Linearisation, keys: Sequence[str]):
    """Whitened linear design and parameter columns of a (hypothetical) design under `twin`."""
    ch = Channels(ch_design, twin, rate_weights(ch_design, twin), lin.ch.sigma0_radps, lin.ch.sigma_tau_s)
    base = cl.apply(twin, [], [], lin.fixed)
    pred = predict(ch_design, base)
    fps = [next(fp for fp in lin.params if fp.key == k) for k in keys]

    def cfg_of(j: int, h: float) -> TwinConfig:
        fp = fps[j]
        return cl.apply(base, [fp], [lin.p0[fp.key] + h], {})

    cols = model_columns(ch, lin.state.lin.values, cfg_of, [fp.fd_step for fp in fps])
    return linear_design(ch, pred), cols


def _suggest(lin: Linearisation, report: IdentifiabilityReport) -> None:
    """Try each option for every absorbed, degenerate or collinear parameter."""
    flagged: dict[str, list[str]] = {}
    for cid in report.candidates.values():
        for p in cid.params:
            partners = [n for n, _ in p.collinear_with]
            if (p.key in RAW_MEASURES and p.status in ("absorbed", "degenerate", "weak")) or partners:
                p.separating.append(
                    {
                        "test": "raw grating and pulse streams",
                        "effect": RAW_MEASURES.get(p.key, "no direct measurement"),
                    }
                )
            if p.status in ("absorbed", "degenerate") or partners:
                flagged[p.key] = [k for n in partners for k in report.candidates[n].kept]
    if not flagged:
        return
    d, twin = lin.ch.design, lin.ch.twin
    keys = sorted({k for k, partners in flagged.items() for k in [k, *partners]})
    X0 = lin.state.X_white
    C0 = np.column_stack([lin.columns[k] for k in keys])
    n_pos0 = d.positions_deg.size
    for opt in _options(d, twin.station.pulses_per_rev):
        try:
            tw = (
                twin
                if opt.A0_factor == 1.0
                else replace(twin, station=replace(twin.station, A0_m=twin.station.A0_m * opt.A0_factor))
            )
            hd = _hypothetical(d, tw, opt.specs)
            Xh, Ch = _columns_for(hd, tw, lin, keys)
        except Exception:  # an option the twin cannot simulate (a window that never closes)
            continue
        X, n_levels = _stack_levels(X0, n_pos0, d.positions_deg, Xh, hd)
        C = np.vstack([C0, Ch])
        Q, _ = np.linalg.qr(X / np.where(np.linalg.norm(X, axis=0) > 0, np.linalg.norm(X, axis=0), 1.0))
        P = C - Q @ (Q.T @ C)
        col = {k: j for j, k in enumerate(keys)}
        L = X[:, :n_levels]
        QL, _ = np.linalg.qr(L / np.where(np.linalg.norm(L, axis=0) > 0, np.linalg.norm(L, axis=0), 1.0))
        CL = C - QL @ (QL.T @ C)
        for key, partners in flagged.items():
            raw, pr = np.linalg.norm(CL[:, col[key]]), np.linalg.norm(P[:, col[key]])
            rho = pr / raw if raw > 0 else 0.0
            cos = 0.0
            if partners:
                B = _subspace(P[:, [col[k] for k in partners]])
                cos = float(np.linalg.norm(B.T @ (P[:, col[key]] / max(pr, 1e-300))))
            ok = rho >= ABSORBED_RHO and cos < COLLINEAR_COS
            pid = next(p for c in report.candidates.values() for p in c.params if p.key == key)
            pid.separating.append(
                {
                    "test": opt.label,
                    "points_added": len(opt.specs),
                    "fraction_not_absorbed": round(float(rho), 6),
                    "cos_with_collinear_partners": round(cos, 4) if partners else None,
                    "snr_after_projection_at_typical_magnitude": float(pr * pid.scale * report.noise_ratio),
                    "separates": bool(ok),
                }
            )


def _stack_levels(
    X0: np.ndarray, n_pos0: int, pos0: np.ndarray, Xh: np.ndarray, hd: PointDesign
) -> tuple[np.ndarray, int]:
    """Join two whitened linear designs, sharing the static level of positions they have in common."""
    allpos = list(np.round(pos0, 9))
    for p in np.round(hd.positions_deg, 9):
        if p not in allpos:
            allpos.append(p)
    n_all = len(allpos)
    k = X0.shape[1] - n_pos0
    top = np.zeros((X0.shape[0], n_all + k))
    top[:, :n_pos0] = X0[:, :n_pos0]
    top[:, n_all:] = X0[:, n_pos0:]
    nh = hd.positions_deg.size
    bot = np.zeros((Xh.shape[0], n_all + k))
    for j, p in enumerate(np.round(hd.positions_deg, 9)):
        bot[:, allpos.index(p)] = Xh[:, j]
    bot[:, n_all:] = Xh[:, nh:]
    return np.vstack([top, bot]), n_all
