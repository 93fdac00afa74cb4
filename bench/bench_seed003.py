"""Seed 003's figures on simulated sessions: design (Figs. 4-7), harmonics by the orthogonal 4-pose method
(Table 6), and PIGA A's coefficients before and after compensation (Tables 3-4 vs 7).

Two sessions of `multiposition` on config/stations/dual-sim.toml with config/twins/multiposition.toml (the
seed's PIGA, its head angle error and theta0): the seed's arrangement (setup 1 equal acceleration, setup 2
equal angle) and the swapped one, each with both 22-position calibration sequences of A; and a Monte Carlo
of noise draws on the pure functions (the fixture's physics, no station) for the honesty of the
uncertainties (draw k with its own generator, seed [0, k]: the same figures on every executor of
station/fanout.py, `--executor local|dask --scheduler ADDRESS --workers W --results CASES.jsonl`). With
`--rev` below 5 (the seed's 10 pi per window) the white rate noise is rescaled so that every window keeps
the error of a 10 pi window at its position; only the station time shrinks.

    .venv/bin/python bench/bench_seed003.py [--rev 0.125] [--speed 1000] [--seed 3] [--max-window-s 0] [--draws 1000]
        [--executor local|dask] [--scheduler ADDRESS] [--workers W] [--results CASES.jsonl]

Simulation paths: the two sessions through the engine on the deterministic station; the Monte Carlo a shortcut (not
the engine): the fixture's static rates straight from drivers.second_instrument.emulator.static_rates_radps.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers.config import load_station_config
from drivers.second_instrument.emulator import static_rates_radps
from drivers.station import simulated_station
from procedures.multiposition import gravity_field as gf
from procedures.multiposition.design import efficiency_sensitivity, total_test_time_s, uncertainty_factors
from procedures.multiposition.four_pose import PoseWindow, fit_four_pose, harmonic_names
from procedures.multiposition.sequences import SCHEMES, sequence_deg
from procedures.multiposition.static_model import (
    MODELS,
    fit_static,
    relative_fitting_accuracy_g,
    true_static_terms,
    with_angle_uncertainty,
)
from station.cli.controller import StationController
from station.fanout import ExecutorSpec, add_executor_options, run_cases, spec_from_args
from station.session import StationInfo
from station.store import SessionStore
from station.twin.config import TwinConfig
from station.twin.fixture import POSES_DEG, SETUPS

ROOT = Path(__file__).resolve().parents[1]
TERMS = MODELS["seed003"]
TWIN_FILE = ROOT / "config" / "twins" / "multiposition.toml"
SEED_REV = 5.0


def design_figures() -> None:
    st = StationInfo()
    print("Design (pure functions, the seed's PIGA: k0 = 4e-4 rad/s, kz = 0.55 rad/s/g, 10 pi per position)\n")
    print("| n | scheme | sqrt(d) k0+ky | sqrt(d) kz | sqrt(d) kzz-ky | sqrt(d) koq | t_total (min) |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for n in (10, 22, 24, 42):
        for scheme in SCHEMES:
            d = np.sqrt(uncertainty_factors(sequence_deg(scheme, n), TERMS))
            t = total_test_time_s(scheme, n, 10 * math.pi, 4e-4, 0.55, st) / 60
            print(f"| {n} | {scheme} | " + " | ".join(f"{x:.3f}" for x in d) + f" | {t:.0f} |")
    ns = np.arange(6, 81)
    for scheme in SCHEMES:
        es = np.abs(efficiency_sensitivity(scheme, ns, TERMS))
        peak = int(ns[np.nanargmax(es)])
        below = next(int(n) for i, n in enumerate(ns) if np.all(es[i:] < 0.02))
        print(f"\nES(n) {scheme}: largest |ES| {np.nanmax(es):.3f} at n = {peak}; |ES| < 0.02 for every n >= {below}")


def window_noise_radps(twin: TwinConfig, rates: np.ndarray) -> np.ndarray:
    """The twin's white rate noise in a 10 pi window at each rate."""
    tm_s = 10 * math.pi / np.abs(rates)
    return twin.noise.rate_noise_radps * np.sqrt(twin.noise.rate_noise_ref_s / tm_s)


@functools.cache
def _draw_setup() -> tuple:
    """What every draw shares (the twin of TWIN_FILE): head angles, clean rates, calibration heads, truths."""
    twin = TwinConfig.from_toml(TWIN_FILE)
    heads = {s: np.radians((np.array(sequence_deg(sch, 22)) - POSES_DEG[SETUPS[s][0]]) % 360)
             for s, sch in ((1, "equal_acceleration"), (2, "equal_angle"))}  # fmt: skip
    clean = {s: static_rates_radps(twin, s, heads[s]) for s in heads}
    cal_heads = np.radians(sequence_deg("equal_acceleration", 22))
    cal_clean = static_rates_radps(twin, 1, cal_heads)["A"][1]
    truth_h = np.array([twin.effects["index_harmonics"][n] for n in harmonic_names(3)])
    truth_k = true_static_terms(twin.instrument, twin.param("odd_quadratic", "koq"))
    return twin, heads, clean, cal_heads, cal_clean, truth_h, truth_k


def one_draw(k: int) -> dict[str, list[float]]:
    """error/sigma of the harmonics and of A's compensated terms in noise draw k (generator seed [0, k])."""
    twin, heads, clean, cal_heads, cal_clean, truth_h, truth_k = _draw_setup()
    st, rng = StationInfo(), np.random.default_rng([0, k])
    windows = [PoseWindow(i, s, pose, h, r + rng.normal(0.0, n))
               for s, by_inst in clean.items() for i, (pose, rates) in by_inst.items()
               for h, r, n in zip(heads[s], rates, window_noise_radps(twin, rates), strict=True)]  # fmt: skip
    fp = fit_four_pose(windows, TERMS, 3, st)
    rates = cal_clean + rng.normal(0.0, window_noise_radps(twin, cal_clean))
    angles = fp.instrument_angle_rad("A", 1, 1, cal_heads)
    comp = fit_static(angles, rates, TERMS, st)
    total = with_angle_uncertainty(comp, angles, fp.angle_derivatives(cal_heads), fp.angle_covariance("A", 1), st)
    err = comp.values - np.array([truth_k[t] for t in TERMS])
    return {"h": list((fp.harmonics_rad - truth_h) / fp.harmonic_sigmas_rad), "eq49": list(err / comp.sigmas),
            "total": list(err / total.sigmas)}  # fmt: skip


def monte_carlo(draws: int, spec: ExecutorSpec | None = None, results: str | None = None) -> None:
    """Honesty of the uncertainties on the pure functions: spread of error/sigma over noise draws."""
    rows = run_cases(one_draw, list(range(draws)), spec or ExecutorSpec(), results=results,
                     settings={"bench": "seed003", "twin": str(TWIN_FILE.name), "rng": [0]})  # fmt: skip
    z_h, z_49, z_total = ([r[key] for r in rows] for key in ("h", "eq49", "total"))
    print(f"\nMonte Carlo, {draws} noise draws (four-pose sequences and the equal-acceleration calibration of A):")
    for label, names, z in (("harmonics", harmonic_names(3), z_h), ("compensated, eq. 49", TERMS, z_49),
                            ("compensated, harmonics propagated", TERMS, z_total)):  # fmt: skip
        spread = ", ".join(f"{n} {x:.2f}" for n, x in zip(names, np.std(z, axis=0), strict=True))
        print(f"spread of error/σ, {label}: {spread}")


def run_session(twin: TwinConfig, params: dict, seed: int, speed: float):
    config = load_station_config(ROOT / "config" / "stations/dual-sim.toml")
    with tempfile.TemporaryDirectory() as out:
        sim = simulated_station(config, twin, seed=seed, speed=speed)
        store = SessionStore(Path(out) / "station.sqlite")
        try:
            controller = StationController(sim.devices, store, config.station_model(), reports_dir=out)
            t0 = time.perf_counter()
            outcome = controller.run("multiposition", params)
            wall = time.perf_counter() - t0
            station_h = controller.engine.progress.elapsed_s / 3600
            session = store.load_session(outcome.session_uid, with_raw=False)
        finally:
            sim.close()
            store.close()
    return outcome, session, wall, station_h


def report_session(label: str, twin: TwinConfig, session, wall: float, station_h: float) -> None:
    res = gf.analyse_gravity_field(session, TERMS, 3)
    fp = res.four_pose
    truth_h = [twin.effects["index_harmonics"][n] for n in harmonic_names(3)]
    print(f"\n{label}: {station_h:.1f} h of station time in {wall:.0f} s of wall time "
          f"({station_h * 3600 / wall:.0f}x); {len(res.windows)} windows\n")  # fmt: skip
    print("| harmonic | true (rad) | identified (rad) | σ (rad) | error / σ |")
    print("|---|---:|---:|---:|---:|")
    for name, t, v, s in zip(harmonic_names(3), truth_h, fp.harmonics_rad, fp.harmonic_sigmas_rad, strict=True):
        print(f"| {name} | {t:.1e} | {v:.4e} | {s:.1e} | {(v - t) / s:+.2f} |")
    truth = true_static_terms(twin.instrument, twin.param("odd_quadratic", "koq"))
    print("\n| A, 22 positions | term | true | uncompensated ± σ | compensated ± σ (eq. 49) | σ with harmonics |")
    print("|---|---|---:|---:|---:|---:|")
    for cal in res.calibrations:
        for t in TERMS:
            u, c, tot = cal.uncompensated.value(t), cal.compensated.value(t), cal.compensated_total.value(t)
            print(f"| {cal.scheme} | {t} | {truth[t]:.4e} | {u[0]:.4e} ± {u[1]:.1e} | {c[0]:.4e} ± {c[1]:.1e} | "
                  f"{tot[1]:.1e} |")  # fmt: skip
        rfa = [float(np.max(np.abs(relative_fitting_accuracy_g(f)))) for f in (cal.uncompensated, cal.compensated)]
        print(f"| {cal.scheme} | σ residual (rad/s) | | {cal.uncompensated.sigma_residual:.2e} | "
              f"{cal.compensated.sigma_residual:.2e} | |")  # fmt: skip
        print(f"| {cal.scheme} | max relative fitting accuracy (g) | | {rfa[0]:.1e} | {rfa[1]:.1e} | |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", type=float, default=0.125, help="revolutions per window (the seed: 5)")
    ap.add_argument("--speed", type=float, default=1000.0, help="virtual clock speed")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--draws", type=int, default=1000, help="Monte Carlo noise draws on the pure functions")
    ap.add_argument("--max-window-s", type=float, default=0.0, help="the procedure's max_window_s (0: off)")
    add_executor_options(ap)
    args = ap.parse_args()
    design_figures()
    twin = TwinConfig.from_toml(TWIN_FILE)
    monte_carlo(args.draws, spec_from_args(args), args.results)
    noise = dataclasses.replace(twin.noise, rate_noise_ref_s=twin.noise.rate_noise_ref_s * args.rev / SEED_REV)
    twin = dataclasses.replace(twin, noise=noise)
    base = {"precession_rev": args.rev, "alignment_rev": min(args.rev / 2, 1.0), "settle_s": 1.0,
            "max_window_s": args.max_window_s}  # fmt: skip
    swapped = {"setup1_scheme": "equal_angle", "setup2_scheme": "equal_acceleration"}
    for label, schemes in (("setup 1 equal acceleration, setup 2 equal angle (the seed's)", {}),
                           ("setup 1 equal angle, setup 2 equal acceleration", swapped)):  # fmt: skip
        outcome, session, wall, station_h = run_session(twin, base | schemes, args.seed, args.speed)
        assert not outcome.faults, outcome.faults
        report_session(label, twin, session, wall, station_h)


if __name__ == "__main__":
    main()
