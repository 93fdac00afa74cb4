"""Identifiability of each candidate in the session's design, before any ranking.

For every candidate parameter, its whitened column J_p (station.gap.fit.Linearisation)
is projected onto the orthogonal complement of the calibrated terms' columns
(the bias k0 and kz, kzz, ky, k3): r_p = P_perp J_p. Then
- rho = |r_p| / |J_p'| is the fraction of its signature that the calibrated
  coefficients do not absorb (J_p' = J_p without its constant part,
  which the bias k0 always absorbs); rho < ABSORBED_RHO: "absorbed" (the
  parameter is not fitted, it stays at the twin's value);
- |r_p| * scale is the signal-to-noise ratio after projection of an effect of
  typical size, and DETECT_SIGMA / |r_p| the smallest value detectable;
- within a candidate, parameters are kept by pivoted QR of their projected
  columns; one that keeps < ABSORBED_RHO of its norm after its siblings is
  "degenerate" (not separable from them);
- between candidates, the largest canonical correlation of the projected
  column spaces (cosine of the smallest principal angle); >= COLLINEAR_COS:
  "collinear", and the candidates joined by collinearity form a group that
  this design cannot tell apart.
For each parameter that is absorbed, degenerate or collinear, extra test
points are tried (other frequencies, extra positions, a second crank
amplitude, short low-frequency windows) by appending noise-free points of
the twin to the design and recomputing the same numbers; raw streams are
judged from what the grating and pulse records measure directly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.linalg
from scipy import stats

from station.gap import candidates as cl
from station.gap.attribute import ALPHA
from station.gap.design import PointDesign
from station.gap.fit import Channels, Linearisation, ModelFit, linear_design, model_columns
from station.gap.forward import predict
from station.gap.noise import rate_weights
from station.session import Session
from station.twin.config import NoiseModel, TwinConfig
from station.twin.measurement import simulate_point
from station.twin.plan import PointSpec, preset_pulses
from station.twin.precession import WindowNeverClosesError
from station.twin.session_sim import station_info

ABSORBED_RHO = 0.01
# Below it, at a signal 10 times the noise, the part of one candidate that another cannot mimic
# is at least 10 sqrt(1 - 0.9^2) = 4.4 sigma: enough to rank them against the noise and against
# the information criterion's penalty on a candidate with more parameters.
COLLINEAR_COS = 0.9
DETECT_SIGMA = 3.0


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class SeparatingTest:
    """Extra test points tried for one parameter, and what they would change."""

    test: str
    points_added: int
    rho: float
    cos: float | None  # with the collinear partners' columns, None without partners
    snr_white: float  # at typical magnitude, in units of the whitening sigma
    separates: bool

    def to_json(self, noise_ratio: float) -> dict:
        return {
            "test": self.test,
            "points_added": self.points_added,
            "fraction_not_absorbed": round(self.rho, 6),
            "cos_with_collinear_partners": None if self.cos is None else round(self.cos, 4),
            "snr_after_projection_at_typical_magnitude": self.snr_white * noise_ratio,
            "separates": self.separates,
        }


@dataclass
class ParamId:
    key: str
    unit: str
    scale: float
    rho: float  # fraction not absorbed by the calibrated terms
    projected_norm: float  # |P_perp J_p| per unit of the parameter, whitening sigma
    status: str  # identifiable | weak | absorbed | degenerate | no_signature
    collinear_with: list[tuple[str, float]] = field(default_factory=list)
    separating: list[SeparatingTest] = field(default_factory=list)
    raw_stream: str | None = None  # what a raw stream would say about it

    def snr_at_scale(self, noise_ratio: float) -> float:
        return self.projected_norm * self.scale * noise_ratio

    def to_json(self, noise_ratio: float) -> dict:
        pr = self.projected_norm * noise_ratio
        return {
            "parameter": self.key,
            "unit": self.unit,
            "typical_magnitude": self.scale,
            "fraction_not_absorbed": _finite(self.rho),
            "snr_after_projection_at_typical_magnitude": _finite(self.snr_at_scale(noise_ratio)),
            "min_detectable_3sigma": _finite(DETECT_SIGMA / pr) if pr > 0 else None,
            "status": self.status,
            "collinear_with": [{"candidate": n, "cos": round(c, 4)} for n, c in self.collinear_with],
            "separating_test_points": [s.to_json(noise_ratio) for s in self.separating],
            "raw_stream": self.raw_stream,
        }


@dataclass
class CandidateId:
    name: str
    params: list[ParamId]
    kept: list[str]  # parameter keys that are fitted
    collinear_with: list[tuple[str, float]] = field(default_factory=list)

    @property
    def identifiable(self) -> bool:
        """Some parameter keeps a signature off the calibrated terms. Near-collinearity with another candidate
        is reported (collinear_with) but decides nothing: whether a rival reproduces this one's fit within its
        plausible bounds on every channel is judged on the fits (station.gap.attribute)."""
        return bool(self.kept)

    @property
    def reason(self) -> str:
        if not self.kept:
            return "every parameter is absorbed by the calibrated coefficients or leaves no signature"
        weak = [p.key for p in self.params if p.status == "weak"]
        absorbed = [p.key for p in self.params if p.key not in self.kept]
        text = "identifiable"
        if self.collinear_with:
            text += "; in this design nearly collinear with " + ", ".join(
                f"{n} (cos {c:.3f})" for n, c in self.collinear_with
            )
        if absorbed:
            text += f"; not fitted (absorbed or degenerate): {', '.join(absorbed)}"
        if weak:
            text += f"; an effect of typical size is below the noise for {', '.join(weak)}"
        return text

    def to_json(self, noise_ratio: float) -> dict:
        return {
            "name": self.name,
            "identifiable": self.identifiable,
            "reason": self.reason,
            "fitted_parameters": self.kept,
            "collinear_with": [{"candidate": n, "cos": round(c, 4)} for n, c in self.collinear_with],
            "parameters": [p.to_json(noise_ratio) for p in self.params],
        }


@dataclass
class IdentifiabilityReport:
    candidates: dict[str, CandidateId]
    noise_ratio: float = 1.0  # whitening sigma / honest sigma: scales every SNR figure

    @property
    def dropped(self) -> frozenset[str]:
        """Parameter keys that stay at the twin's value (absorbed, degenerate or without signature)."""
        kept = {k for c in self.candidates.values() for k in c.kept}
        return frozenset(p.key for c in self.candidates.values() for p in c.params if p.key not in kept)

    def undetermined(self, name: str) -> list[str]:
        """Parameters of candidate `name` that stay at the twin's value: absorbed by the calibrated terms,
        degenerate with its fitted ones (only their combinations with those are fixed) or without a signature."""
        c = self.candidates.get(name)
        return [] if c is None else [p.key.split(".", 1)[1] for p in c.params if p.key not in c.kept]

    def fittable(self) -> list[str]:
        return [n for n, c in self.candidates.items() if c.kept]

    def group(self, name: str) -> list[str]:
        """`name` and every candidate joined to it by collinearity (the set this design cannot tell apart)."""
        seen, todo = [name], [name]
        while todo:
            for other, _ in self.candidates[todo.pop()].collinear_with:
                if other not in seen:
                    seen.append(other)
                    todo.append(other)
        return seen

    def separating_tests(self, names: Sequence[str]) -> list[str]:
        """Tests that separate every collinear parameter of these candidates (tried by `suggest`)."""
        flagged = [p for n in names for p in self.candidates[n].params if p.collinear_with and p.separating]
        if not flagged:
            return []
        ok = [{s.test for s in p.separating if s.separates} for p in flagged]
        return [s.test for s in flagged[0].separating if all(s.test in o for o in ok)]

    def to_json(self) -> dict:
        return {
            "method": "columns of each parameter projected off the calibrated terms (bias k0, kz, kzz, "
            f"ky, k3); absorbed if the fraction kept < {ABSORBED_RHO}; collinear if the cosine of the smallest "
            f"principal angle between two candidates' projected columns >= {COLLINEAR_COS}",
            "candidates": [c.to_json(self.noise_ratio) for c in self.candidates.values()],
        }


def subspace(cols: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the columns' span."""
    if cols.shape[1] == 0:
        return cols
    U, s, _ = np.linalg.svd(cols, full_matrices=False)
    return U[:, s > 1e-9 * s.max()] if s.max() > 0 else U[:, :0]


def principal_cos(A: np.ndarray, B: np.ndarray) -> float:
    """Cosine of the smallest principal angle between two orthonormal bases."""
    if A.shape[1] == 0 or B.shape[1] == 0:
        return 0.0
    return float(np.linalg.svd(A.T @ B, compute_uv=False).max())


def _param_status(lin: Linearisation, fp: cl.FreeParam, projected: np.ndarray) -> ParamId:
    raw = float(np.linalg.norm(lin.project_levels(lin.columns[fp.key][:, None])))
    pr = float(np.linalg.norm(projected))
    rho = pr / raw if raw > 0 else math.nan
    status = "no_signature" if raw == 0 else ("absorbed" if rho < ABSORBED_RHO else "identifiable")
    if status == "identifiable" and pr * fp.scale < 1.0:
        status = "weak"
    return ParamId(fp.key, fp.unit, fp.scale, rho, pr, status)


def _kept(params: list[ParamId], proj: dict[str, np.ndarray]) -> list[str]:
    """Parameters kept by pivoted QR of their unit-norm projected columns; the others are degenerate."""
    live = [p for p in params if p.status in ("identifiable", "weak")]
    if not live:
        return []
    M = np.column_stack([proj[p.key] / np.linalg.norm(proj[p.key]) for p in live])
    _, R, piv = scipy.linalg.qr(M, mode="economic", pivoting=True)
    keep = set()
    for d, j in zip(np.abs(np.diag(R)), piv, strict=False):
        if d < ABSORBED_RHO:
            live[j].status = "degenerate"
        else:
            keep.add(live[j].key)
    return [p.key for p in params if p.key in keep]  # table order


def _candidate_ids(
    lin: Linearisation, proj: dict[str, np.ndarray]
) -> tuple[dict[str, CandidateId], dict[str, np.ndarray]]:
    """Each candidate's parameters' status and its kept parameters, and the span of their projected columns."""
    out: dict[str, CandidateId] = {}
    spaces: dict[str, np.ndarray] = {}
    for name, cand in lin.cands.items():
        params = [_param_status(lin, fp, proj[fp.key]) for fp in cand.free]
        kept = _kept(params, proj)
        spaces[name] = subspace(np.column_stack([proj[k] for k in kept])) if kept else np.zeros((lin.n_rows, 0))
        out[name] = CandidateId(name, params, kept)
    return out, spaces


def _near(v: np.ndarray, names: Sequence[str], spaces: dict[str, np.ndarray]) -> list[tuple[str, float]]:
    """The candidates of `names` whose span holds the unit vector v at cos >= COLLINEAR_COS, closest first."""
    cos = [(n, float(np.linalg.norm(spaces[n].T @ v))) for n in names]
    return sorted([(n, c) for n, c in cos if c >= COLLINEAR_COS], key=lambda x: -x[1])


def _collinear(
    cid: CandidateId, others: Sequence[str], spaces: dict[str, np.ndarray], proj: dict[str, np.ndarray]
) -> None:
    """The candidates collinear with `cid` (smallest principal angle), and for each kept parameter those whose
    span holds its column."""
    cos = [(other, principal_cos(spaces[cid.name], spaces[other])) for other in others if other != cid.name]
    cid.collinear_with = sorted([(n, c) for n, c in cos if c >= COLLINEAR_COS], key=lambda x: -x[1])
    partners = [n for n, _ in cid.collinear_with]
    for p in cid.params:
        if p.key in cid.kept:
            p.collinear_with = _near(proj[p.key] / np.linalg.norm(proj[p.key]), partners, spaces)


def _raw_stream(p: ParamId, has_raw: bool) -> None:
    """Where a raw stream measures a parameter the rates fix poorly (absorbed, degenerate, weak or collinear)."""
    effect, _, name = p.key.partition(".")
    measures = cl.LIBRARY[effect].effect.params[name].raw_measures  # piga-session/1 raw/<point_id>.npz
    if measures and (p.status in ("absorbed", "degenerate", "weak") or p.collinear_with):
        p.raw_stream = ("recorded in this session (see where.raw_streams): " if has_raw else "") + measures


def assess(lin: Linearisation, suggest: bool = True, has_raw: bool = False) -> IdentifiabilityReport:
    """Absorbed / degenerate / collinear status of every candidate and parameter of the library."""
    proj = {k: lin.project(c[:, None])[:, 0] for k, c in lin.columns.items()}
    out, spaces = _candidate_ids(lin, proj)
    for cid in out.values():
        _collinear(cid, list(out), spaces, proj)
        for p in cid.params:
            _raw_stream(p, has_raw)
    report = IdentifiabilityReport(out)
    if suggest:
        _suggest(lin, report)
    return report


# ----------------------------------------------------------------------------- seen only at rest

# A parameter is seen only at rest when its signature per vibration row is below this fraction of its
# signature per static row (and so are the period identities' and the grating's, in information).
REST_ONLY_RATIO = 0.1
# Its fit carries the effect when |value| / sd exceeds the two-sided 1-dof test at ALPHA (station.gap.attribute).
REST_ONLY_Z = float(stats.norm.isf(ALPHA / 2))
PULSE_TEST_HOW = "the pulse record (raw pulse_t with pulse_dir at vibration points) would test it"


def seen_only_at_rest(fit: ModelFit, ch: Channels) -> dict[str, list[str]]:
    """Chosen effects' parameters fitted significantly (|v| / sd > REST_ONLY_Z) that only the static rows see.

    Such a parameter is what the effect says the table does at rest, the crank at psi = 0 (physics.md):
    parasitic_rotation's axc1 tilts the input axis by alpha_x(0) = axc1 at rest, while in vibration
    its first-order rate term -kz sin(theta) (1 - a sin psi) axc1 cos psi has a zero window mean over
    whole periods (<cos psi> = <sin psi cos psi> = 0; the kzz, ky, k3 terms alike): the rates, period
    identities and grating see only the rest value, which any rocking shape with that value at rest (a
    tilt at 2 psi, say) gives as well. Only the pulse edges see the shape (its rate harmonics), so
    without a pulse record the effect's attribution rests on an assumption this session cannot test."""
    d = ch.design
    n, stat = ch.n_rate, ~d.vib
    if not stat.any() or not d.vib.any():
        return {}
    unwhite = ch.sigma0_radps / np.sqrt(ch.weights)
    n_lin = fit.J.shape[1] - len(fit.free)
    out: dict[str, list[str]] = {}
    for j, (fp, v, sd) in enumerate(zip(fit.free, fit.values, fit.sigmas, strict=True)):
        col = fit.J[:, n_lin + j]
        raw = col[:n] * unwhite
        rest, motion = float(np.sqrt(np.mean(raw[stat] ** 2))), float(np.sqrt(np.mean(raw[d.vib] ** 2)))
        other2, rest2 = float(col[n:] @ col[n:]), float(col[:n][stat] @ col[:n][stat])
        if rest <= 0 or motion > REST_ONLY_RATIO * rest or other2 > REST_ONLY_RATIO**2 * rest2:
            continue
        if sd > 0 and abs(v) > REST_ONLY_Z * sd:
            out.setdefault(fp.effect, []).append(fp.param)
    return out


# ----------------------------------------------------------------------------- separating test points


@dataclass(frozen=True)
class _Option:
    label: str
    specs: tuple[PointSpec, ...]
    A0_factor: float = 1.0


def _new_frequencies(design: PointDesign, freqs: list[float], pulses_per_rev: int) -> list[_Option]:
    """2, 4 and 6 Hz where the session has none within 0.5 Hz, at every position, and the first of them with short
    windows (1 precession revolution)."""
    pos = [float(p) for p in design.positions_deg]
    new = [f for f in (2.0, 4.0, 6.0) if all(abs(f - g) > 0.5 for g in freqs)]
    opts = [
        _Option(f"add {f:g} Hz at every position", tuple(PointSpec(p, f, _preset_for(design, p)) for p in pos))
        for f in new
    ]
    if new:
        label = f"add {new[0]:g} Hz with short windows (1 precession revolution) at every position"
        opts.append(_Option(label, tuple(PointSpec(p, new[0], pulses_per_rev) for p in pos)))
    return opts


def _half_way_positions(design: PointDesign, freqs: list[float]) -> list[_Option]:
    """Positions half-way between the recorded ones (the smallest step), each at the session's frequencies and
    at rest; positions near 90 and 270 deg cost hours (physics.md) and are left out."""
    pos = [float(p) for p in design.positions_deg]
    if len(pos) < 2:
        return []
    step = float(np.min(np.diff(sorted(pos))))
    new = [p + step / 2 for p in pos if abs(math.cos(math.radians(p + step / 2))) > 0.2]
    specs = [PointSpec(p, f, pp) for p in new for pp in [_preset_for(design, p)] for f in [*freqs, 0.0]]
    return [_Option(f"add {len(new)} positions half-way between the recorded ones", tuple(specs))]


def _half_amplitude(design: PointDesign, freqs: list[float]) -> list[_Option]:
    """The vibration points again with the crank amplitude A0/2."""
    if not freqs:
        return []
    pos = [float(p) for p in design.positions_deg]
    specs = tuple(PointSpec(p, f, _preset_for(design, p)) for p in pos for f in freqs)
    return [_Option("repeat the vibration points with a second crank amplitude A0/2", specs, A0_factor=0.5)]


def _options(design: PointDesign, pulses_per_rev: int) -> list[_Option]:
    """Extra test points to try: each is a set of points added to the recorded design."""
    freqs = sorted({float(f) for f in design.freq_hz[design.vib]})
    return (
        _new_frequencies(design, freqs, pulses_per_rev)
        + _half_way_positions(design, freqs)
        + _half_amplitude(design, freqs)
    )


def _preset_for(design: PointDesign, position_deg: float) -> int:
    """Preset count for about the session's median window at this position (seed 000 5.1.4)."""
    cos = np.abs(np.cos(design.theta_rad))
    ok = cos > 0.3
    gain = float(np.median(np.abs(design.rate_radps[ok]) / cos[ok])) if ok.any() else 0.56
    return preset_pulses(position_deg, float(np.median(design.Tm_s)), kz_nominal=gain, k0_nominal=0.0)


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
    return PointDesign.from_session(Session(station_info(twin), recs))


def _columns_for(design: PointDesign, twin: TwinConfig, lin: Linearisation, keys: Sequence[str]):
    """Whitened linear design and parameter columns of a (hypothetical) design under `twin`."""
    ch = Channels(design, twin, rate_weights(design, twin), lin.ch.sigma0_radps, lin.ch.sigma_tau_s)
    base = cl.apply(twin, [], [], lin.fixed)
    fps = [lin.param(k) for k in keys]

    def cfg_of(j: int, h: float) -> TwinConfig:
        fp = fps[j]
        return cl.apply(base, [fp], [lin.p0[fp.key] + h], {})

    cols = model_columns(ch, lin.state.lin.values, cfg_of, [fp.fd_step for fp in fps])
    return linear_design(ch, predict(design, base)), cols


def _unit_norm(M: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(M, axis=0)
    return M / np.where(n > 0, n, 1.0)


def _flagged(report: IdentifiabilityReport) -> dict[str, list[str]]:
    """Every absorbed, degenerate or collinear parameter, with the kept parameters of its collinear partners."""
    flagged: dict[str, list[str]] = {}
    for cid in report.candidates.values():
        for p in cid.params:
            partners = [n for n, _ in p.collinear_with]
            if p.status in ("absorbed", "degenerate") or partners:
                flagged[p.key] = [k for n in partners for k in report.candidates[n].kept]
    return flagged


def _option_twin(twin: TwinConfig, opt: _Option) -> TwinConfig:
    """The twin that runs an option's points (its crank amplitude scaled by A0_factor)."""
    if opt.A0_factor == 1.0:
        return twin
    return replace(twin, station=replace(twin.station, A0_m=twin.station.A0_m * opt.A0_factor))


def _projected_with(lin: Linearisation, opt: _Option, keys: Sequence[str]) -> tuple[np.ndarray, np.ndarray] | None:
    """The parameters' columns over the recorded design with the option's points added, projected off the
    calibrated terms (P) and off the bias k0 alone (CL); None where the twin cannot run the option."""
    d, tw = lin.ch.design, _option_twin(lin.ch.twin, opt)
    try:
        hd = _hypothetical(d, tw, opt.specs)
    except WindowNeverClosesError:  # an option the twin cannot run (a rate too small to close a window)
        return None
    Xh, Ch = _columns_for(hd, tw, lin, keys)
    X = np.vstack([lin.state.X_white, Xh])  # one bias k0 shared by both
    C = np.vstack([np.column_stack([lin.columns[k] for k in keys]), Ch])
    Q, _ = np.linalg.qr(_unit_norm(X))
    QL, _ = np.linalg.qr(_unit_norm(X[:, : d.n_levels]))
    return C - Q @ (Q.T @ C), C - QL @ (QL.T @ C)


def _separation(
    pid: ParamId, label: str, n_points: int, p_col: np.ndarray, cl_col: np.ndarray, B: np.ndarray | None
) -> SeparatingTest:
    """The option as a separating test of one parameter: the fraction of its column kept off the calibrated terms
    (rho = |P c| / |C_L c|) and its cosine with the partners' span B; it separates when rho >= ABSORBED_RHO and
    cos < COLLINEAR_COS."""
    raw, pr = float(np.linalg.norm(cl_col)), float(np.linalg.norm(p_col))
    rho = pr / raw if raw > 0 else 0.0
    cos = None if B is None else float(np.linalg.norm(B.T @ (p_col / max(pr, 1e-300))))
    ok = rho >= ABSORBED_RHO and (cos is None or cos < COLLINEAR_COS)
    return SeparatingTest(label, n_points, rho, cos, pr * pid.scale, ok)


def _suggest(lin: Linearisation, report: IdentifiabilityReport) -> None:
    """Try each option for every absorbed, degenerate or collinear parameter."""
    flagged = _flagged(report)
    if not flagged:
        return
    pids = {p.key: p for c in report.candidates.values() for p in c.params}
    keys = sorted({k for key, partners in flagged.items() for k in [key, *partners]})
    col = {k: j for j, k in enumerate(keys)}
    for opt in _options(lin.ch.design, lin.ch.twin.station.pulses_per_rev):
        projected = _projected_with(lin, opt, keys)
        if projected is None:
            continue
        P, CL = projected
        for key, partners in flagged.items():
            B = subspace(P[:, [col[k] for k in partners]]) if partners else None
            test = _separation(pids[key], opt.label, len(opt.specs), P[:, col[key]], CL[:, col[key]], B)
            pids[key].separating.append(test)
