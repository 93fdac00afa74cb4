"""Validation cases for the gap diagnosis: one independent session directory and its truth.

Contract (the gap diagnosis is scored against it):

    make_case(seed, kind, out_dir, *, snr=None, family=None, raw=None) -> dict

kind is "null", a library effect name (`LIBRARY`), "pair:A+B" (two library effects, each scaled
to `snr` on its own channel, then both applied) or "ool:<name>" (`OUT_OF_LIBRARY`). family None
and raw None are drawn from the seed; snr None is drawn from (5, 10, 30). The same seed gives the
same design, instrument, noise and crank phases whatever the kind (so a null and an effect case of
one seed differ only by the effect); the same seed and kind give the same directory bit for bit.

Returned truth (JSON-able): kind, effects, params {effect: {param: value}}, in_library, family,
n_points, raw, snr (requested; None for null), snr_achieved {effect: snr}, channel (the channel
each effect was scaled on; "A_channel+B_channel" for pairs), separable (pairs: whether each
signature stays >= SEPARABLE_SIGMA away from everything the other effect's parameters reproduce,
linearised, on all channels of this session; None otherwise), noise {...,"stated": bool},
coefficients, plausible (every parameter within its physical bound), seed, design.
`case_mimic(seed, kind, ...)` tells, for an out-of-library case, which library effect comes
closest on all channels and whether it stays within plausible bounds (a case no diagnosis can
tell from the library); it is slow, so make_case leaves it out.

    python -m indep.cases OUT_DIR --n N [--seed S] [--mimic]   (PYTHONPATH=tests)

writes N cases (nulls, each library effect at SNR 5/10/30, pairs, out-of-library) as
OUT_DIR/case_XXXX/ with one JSON line per case in OUT_DIR/truth.jsonl.
"""

from __future__ import annotations

import argparse
import json
import math
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from indep.effects import (
    EFFECTS,
    LIBRARY,
    OUT_OF_LIBRARY,
    Context,
    combined,
    scale_to_snr,
    signature,
    with_effect,
)
from indep.generator import (
    FAMILIES,
    Truth,
    draw_session,
    plan_pulses,
    random_coefficients,
    random_design,
    random_noise,
    simulate,
    write_session,
)
from indep.world import Coefficients

__all__ = ["FAMILIES", "LIBRARY", "OUT_OF_LIBRARY", "SNR_LEVELS", "make_case"]
SNR_LEVELS = (5.0, 10.0, 30.0)
SEPARABLE_SIGMA = 3.0
_MIN_STATIC_RATE = 3e-6  # rad/s: k0 is redrawn until every static rate is at least this (window rule)


def _parse_kind(kind: str) -> tuple[list[str], bool]:
    if kind == "null":
        return [], True
    if kind.startswith("pair:"):
        names = kind[5:].split("+")
        if len(names) != 2 or any(n not in LIBRARY for n in names) or names[0] == names[1]:
            raise ValueError(f"kind={kind!r}: a pair is 'pair:A+B' with two different effects of {LIBRARY}")
        return names, True
    if kind.startswith("ool:"):
        name = kind[4:]
        if name not in OUT_OF_LIBRARY:
            raise ValueError(f"kind={kind!r}: out-of-library effects are {OUT_OF_LIBRARY}")
        return [name], False
    if kind in LIBRARY:
        return [kind], True
    raise ValueError(f"kind={kind!r}: allowed 'null', {LIBRARY}, 'pair:A+B' or 'ool:<name>' with {OUT_OF_LIBRARY}")


def _jsonable(x: object) -> object:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


def _context(seed: int, family: str | None, raw: bool | None) -> tuple[Context, bool, np.random.Generator]:
    rng = np.random.default_rng([seed, 0])
    fam = family if family is not None else FAMILIES[int(rng.integers(len(FAMILIES)))]
    if fam not in FAMILIES:
        raise ValueError(f"family={fam!r}: allowed {FAMILIES}")
    with_raw = bool(rng.random() < 0.5) if raw is None else bool(raw)
    state_noise = bool(rng.random() < 0.7)
    design = random_design(rng, fam)
    co = random_coefficients(rng)
    for _ in range(50):  # keep every static rate away from zero (module docstring of generator)
        rates = [abs(_static_rate(co, th)) for th in design.positions_deg]
        if min(rates) >= _MIN_STATIC_RATE:
            break
        co = random_coefficients(rng)
    noise = random_noise(rng)
    truth = Truth(co, noise=noise)
    plan = plan_pulses(design, co)
    draws = draw_session(rng, len(plan), with_raw, plan)
    ctx = Context(design, truth, draws, plan, with_raw)
    ctx.rows0 = simulate(design, truth, draws, plan)
    return ctx, state_noise, rng


def _static_rate(co: Coefficients, theta_deg: float) -> float:
    from indep.generator import nominal_rate

    return nominal_rate(co, theta_deg, 0.0)


def _linear_family(ctx: Context, truth: Truth, name: str, params: dict[str, float]) -> np.ndarray:
    """Columns: d(combined signature)/d(parameter) of one effect at its parameters (finite differences)."""
    eff = EFFECTS[name]
    s0 = combined(signature(ctx, with_effect(truth, eff, params)), ctx)
    cols = []
    for k, v in params.items():
        if not isinstance(v, float) or k in ("pattern_seed", "order_seed", "n_windows"):
            continue
        h = 1e-3 * abs(v) if v else 1e-3 * eff.bounds.get(k, 1.0)
        p = dict(params)
        p[k] = v + h
        cols.append((combined(signature(ctx, with_effect(truth, eff, p)), ctx) - s0) / h)
    return np.array(cols).T


def _distance(v: np.ndarray, J: np.ndarray) -> float:
    """Distance of v from the column span of J (whitened units: standard deviations)."""
    return _fit(v, J)[0]


def _fit(v: np.ndarray, J: np.ndarray) -> tuple[float, np.ndarray]:
    if J.size == 0:
        return float(np.linalg.norm(v)), np.zeros(0)
    x = np.linalg.lstsq(J, v, rcond=None)[0]
    return float(np.linalg.norm(v - J @ x)), x


def library_mimic(ctx: Context, sig: np.ndarray) -> dict:
    """The library effect whose linearised parameters come closest to a signature on all channels.

    Each library effect's Jacobian is taken at zero (finite steps of 1e-3 of its plausible bound);
    returns the closest effect, the distance left (standard deviations) and whether the fitted
    parameters stay within the plausible bounds. An out-of-library case with a small distance and
    fitted parameters within bounds is one that no diagnosis can tell from a library effect.
    """
    s0 = combined(signature(ctx, ctx.truth), ctx)
    best: dict = {"effect": None, "distance_sigma": math.inf, "within_bounds": False, "skipped": []}
    for name in LIBRARY:
        try:
            d, x, bounds = _mimic_fit(ctx, sig, s0, name)
        except ValueError as exc:  # a probe step the design cannot run (a rate through zero: no first passage)
            best["skipped"].append(f"{name}: {exc}"[:200])
            continue
        if d < best["distance_sigma"]:
            best.update(effect=name, distance_sigma=d, within_bounds=bool(np.all(np.abs(x) <= bounds)))
    return best


def _mimic_fit(ctx: Context, sig: np.ndarray, s0: np.ndarray, name: str) -> tuple[float, np.ndarray, np.ndarray]:
    """Distance of sig from one library effect's linearised span, the fitted parameters and their bounds."""
    eff = EFFECTS[name]
    p0 = {k: 0.0 for k in eff.bounds}
    if name == "lateral_resonance":  # linearise in kx L0^2 about a mid resonance
        p0 = {"L0": 0.0, "fr_hz": 1.5 * max(ctx.design.freqs_hz), "Q": 8.0, "phiL_rad": 0.0, "kx": 0.0}
        cols, keys = [], ["kxL2"]
        p = dict(p0, L0=0.01, kx=1e-5)
        cols.append((combined(signature(ctx, with_effect(ctx.truth, eff, p)), ctx) - s0) / 1e-9)
        J, bounds = np.array(cols).T, np.array([eff.bounds["kx"] * eff.bounds["L0"] ** 2])
    else:
        cols, keys = [], list(p0)
        for k in keys:
            h = 1e-3 * eff.bounds[k]
            cols.append((combined(signature(ctx, with_effect(ctx.truth, eff, dict(p0, **{k: h}))), ctx) - s0) / h)
        J, bounds = np.array(cols).T, np.array([eff.bounds[k] for k in keys])
    d, x = _fit(sig, J)
    return d, x, bounds


@dataclass
class _Built:
    ctx: Context
    state_noise: bool
    rng: np.random.Generator
    names: list[str]
    in_library: bool
    snr: float | None
    params: dict
    channels: dict
    achieved: dict
    truth: Truth


def _build(seed: int, kind: str, snr: float | None, family: str | None, raw: bool | None) -> _Built:
    """The case's world: design, noise, and each effect drawn and scaled to snr on its channel."""
    names, in_library = _parse_kind(kind)
    if snr is not None and not (isinstance(snr, (int, float)) and math.isfinite(snr) and snr > 0):
        raise ValueError(f"snr={snr!r}: must be a finite number > 0")
    ctx, state_noise, rng = _context(int(seed), family, raw)
    rng_eff = np.random.default_rng([int(seed), 1, zlib.crc32(kind.encode())])
    if names and snr is None:
        snr = float(rng_eff.choice(SNR_LEVELS))
    truth, params, channels, achieved = ctx.truth, {}, {}, {}
    for name in names:
        eff = EFFECTS[name]
        p0 = eff.draw(rng_eff, ctx)
        assert snr is not None
        params[name], channels[name], achieved[name] = scale_to_snr(eff, p0, float(snr), ctx)
    for name in names:
        truth = with_effect(truth, EFFECTS[name], params[name])
    return _Built(ctx, state_noise, rng, names, in_library, snr, params, channels, achieved, truth)


def case_mimic(
    seed: int, kind: str, *, snr: float | None = None, family: str | None = None, raw: bool | None = None
) -> dict | None:
    """For an out-of-library case of make_case: the library effect that comes closest (library_mimic).

    None for library kinds. Costs one noise-free session per library parameter (seconds), hence
    not part of make_case; `python -m indep.cases --mimic` adds it to truth.jsonl.
    """
    b = _build(seed, kind, snr, family, raw)
    if b.in_library:
        return None
    eff = EFFECTS[b.names[0]]
    sig = combined(signature(b.ctx, with_effect(b.ctx.truth, eff, b.params[b.names[0]])), b.ctx)
    return library_mimic(b.ctx, sig - combined(signature(b.ctx, b.ctx.truth), b.ctx))


def make_case(
    seed: int,
    kind: str,
    out_dir: Path,
    *,
    snr: float | None = None,
    family: str | None = None,
    raw: bool | None = None,
) -> dict:
    """Write one session directory for (seed, kind) and return its truth (module docstring)."""
    b = _build(seed, kind, snr, family, raw)
    ctx, state_noise, rng, names, in_library, snr = b.ctx, b.state_noise, b.rng, b.names, b.in_library, b.snr
    params, channels, achieved, truth = b.params, b.channels, b.achieved, b.truth
    separable = None
    if len(names) == 2:
        a, b = names
        sig_a = combined(signature(ctx, with_effect(ctx.truth, EFFECTS[a], params[a])), ctx)
        sig_b = combined(signature(ctx, with_effect(ctx.truth, EFFECTS[b], params[b])), ctx)
        sig_0 = combined(signature(ctx, ctx.truth), ctx)
        ja = _linear_family(ctx, ctx.truth, a, params[a])
        jb = _linear_family(ctx, ctx.truth, b, params[b])
        d_ab = _distance(sig_b - sig_0, ja)
        d_ba = _distance(sig_a - sig_0, jb)
        separable = bool(min(d_ab, d_ba) >= SEPARABLE_SIGMA)
    plausible = all(
        abs(v) <= EFFECTS[n].bounds.get(k, math.inf)
        for n in names
        for k, v in params[n].items()
        if isinstance(v, float)
    )
    noise_rng = np.random.default_rng([int(seed), 2])
    rows = write_session(
        Path(out_dir),
        ctx.design,
        truth,
        noise_rng,
        raw=ctx.raw,
        state_noise=state_noise,
        draws=ctx.draws,
        plan=ctx.plan,
        raw_optional=(bool(rng.random() < 0.5), bool(rng.random() < 0.5)),
    )
    noise = ctx.truth.noise
    assert noise is not None
    d = ctx.design
    return _jsonable(
        {
            "kind": kind,
            "effects": names,
            "params": params,
            "in_library": in_library,
            "family": d.family,
            "n_points": len(rows),
            "raw": ctx.raw,
            "snr": snr if names else None,
            "snr_achieved": achieved,
            "channel": "+".join(channels[n] for n in names) if names else None,
            "separable": separable,
            "noise": {**noise.as_dict(), "stated": state_noise},
            "coefficients": ctx.truth.co.as_dict(),
            "plausible": plausible,
            "seed": int(seed),
            "design": {
                "positions_deg": list(d.positions_deg),
                "freqs_hz": list(d.freqs_hz),
                "window_revs": d.window_revs,
                "static_repeats": d.static_repeats,
                "order": d.order,
                "max_window_s": d.max_window_s,
                "session_s": rows[-1].start_s + rows[-1].true_Tm_s,
            },
        }
    )  # type: ignore[return-value]


def batch_kinds(n: int, rng: np.random.Generator) -> list[tuple[str, float | None]]:
    """A mix of kinds: nulls, library effects at each SNR level, pairs, out-of-library effects."""
    kinds: list[tuple[str, float | None]] = []
    pool = [("null", None)]
    pool += [(e, s) for e in LIBRARY for s in SNR_LEVELS]
    pool += [(f"ool:{e}", 10.0) for e in OUT_OF_LIBRARY]
    for _ in range(n):
        u = rng.random()
        if u < 0.15:
            kinds.append(("null", None))
        elif u < 0.3:
            a, b = rng.choice(LIBRARY, 2, replace=False)
            kinds.append((f"pair:{a}+{b}", float(rng.choice(SNR_LEVELS))))
        else:
            kinds.append(pool[int(rng.integers(len(pool)))])
    return kinds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m indep.cases", description=__doc__.split("\n")[0])
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0, help="seed of the first case")
    ap.add_argument("--mimic", action="store_true", help="add library_mimic to out-of-library cases (slow)")
    args = ap.parse_args(argv)
    if args.n < 1:
        ap.error(f"--n {args.n}: must be >= 1")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    kinds = batch_kinds(args.n, np.random.default_rng([args.seed, 99]))
    with (args.out_dir / "truth.jsonl").open("w") as fh:
        for k, (kind, snr) in enumerate(kinds):
            case_dir = args.out_dir / f"case_{k:04d}"
            truth = make_case(args.seed + k, kind, case_dir, snr=snr)
            truth["dir"] = case_dir.name
            if args.mimic and not truth["in_library"]:
                truth["library_mimic"] = case_mimic(args.seed + k, kind, snr=snr)
            fh.write(json.dumps(truth, sort_keys=True) + "\n")
            print(f"{case_dir.name}: {kind} snr={truth['snr']} {truth['family']} n={truth['n_points']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
