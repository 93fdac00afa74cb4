"""Monte Carlo of the seed-000 uncertainty budget: is U (95 %) a 95 % interval? (issue 15, deliverables 4, 5, 7)

Each session is simulated by the twin's fast path (station.twin.session_sim) with every Type B input of the
budget drawn from its stated distribution (normal, standard deviation u from config/instruments/
references.toml, times `--b-scale`): crank radius A0 and g differ from the station's recorded values,
the table has a parasitic translation z0, a parasitic rotation axs1, second harmonics Zs2 and Zc2, a
frequency error eps_f and a read-head latency. The session is then identified (weighted joint least
squares) and budgeted (procedures.integral_precession.budget); per coefficient we report the mean and spread of
(k_hat - k) / u_c and the fraction of sessions with |k_hat - k| <= U (target 0.93-0.97).

Designs: `integral` (seed 000: 10 positions x 8, 9, 10 Hz + static, dof 26), `multi` (the multi-frequency
method at 0, 45, 180 deg, dof 5), `unequal` (10 positions, each window 140, 280, 560 or 1120 s at random,
white rate noise: compares equal weights with the weighted fit).

    .venv/bin/python bench/bench_mc_seed000.py [--design integral|multi|unequal] [--n 300] [--b-scale 1]

Simulation path: the session_sim shortcut (not the engine): station.twin.session_sim with the drawn twin, for the
budget's
honesty (an uncertainty study of the identification; tests/test_simulation_paths.py holds the shortcut statistically
equal to the engine on the default twin).
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace

import numpy as np

from procedures.common.references import load_references
from procedures.integral_precession.budget import seed000_budget
from procedures.integral_precession.identify import identify
from station.session import StationInfo
from station.twin.config import default_twin
from station.twin.plan import PointSpec, equal_angle_positions_deg, multiposition_plan, preset_pulses, seed000_plan
from station.twin.session_sim import simulate_session

NAMES = ("kz", "kzz", "ky", "k3")


def unequal_plan(rng: np.random.Generator) -> list[PointSpec]:
    """10 positions, every window (vibration and static) 140, 280, 560 or 1120 s at random."""
    plan = []
    for pos in equal_angle_positions_deg(10):
        for f in (8.0, 9.0, 10.0, 0.0):
            plan.append(PointSpec(pos, f, preset_pulses(pos, float(rng.choice([140.0, 280.0, 560.0, 1120.0])))))
    return plan


def drawn_twin(rng: np.random.Generator, refs, b_scale: float):
    """The default twin with every Type B input drawn from N(0, (b_scale u)^2); the station as recorded."""
    cfg = default_twin()
    u = {k: r.standard_uncertainty * b_scale for k, r in refs.items()}
    st = cfg.station
    true_station = replace(st, A0_m=st.A0_m + rng.normal(0, u["A0_m"]), g_mps2=st.g_mps2 + rng.normal(0, u["g_mps2"]))
    cfg = replace(cfg, station=true_station)
    cfg = cfg.with_effect("waveform_fundamental", z0=rng.normal(0, u["zs1_z0_m"]))
    cfg = cfg.with_effect("waveform_harmonics", Zs2=rng.normal(0, u["second_harmonic_m"]),
                          Zc2=rng.normal(0, u["second_harmonic_m"]))  # fmt: skip
    cfg = cfg.with_effect("parasitic_rotation", axs1=rng.normal(0, u["axs1_rad"]))
    cfg = cfg.with_effect("frequency_error", eps_f=rng.normal(0, u["eps_f"]))
    cfg = cfg.with_effect("readhead_latency", delta=rng.normal(0, u["readhead_latency_s"]))
    recorded = StationInfo(st.A0_m, st.latitude_deg, st.g_mps2, st.earth_rate_radps, st.pulses_per_rev)
    return cfg, recorded


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", choices=("integral", "multi", "unequal"), default="integral")
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--b-scale", type=float, default=1.0, help="scale of every Type B input (drawn and budgeted)")
    ap.add_argument("--seed", type=int, default=20_000)
    args = ap.parse_args()
    refs = load_references()
    scaled = {k: replace(r, standard_uncertainty=r.standard_uncertainty * args.b_scale) for k, r in refs.items()}
    truth0 = default_twin().instrument
    truth = np.array([truth0.kz, truth0.kzz, truth0.ky, truth0.k3])
    z_u, z_a, cover, cover_a, z_eq, dofs, mu_rej = [], [], [], [], [], [], []
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    for i in range(args.n):
        if args.design == "integral":
            plan = seed000_plan()
        elif args.design == "multi":
            plan = multiposition_plan([0.0, 45.0, 180.0], [8.0, 9.0, 10.0], 560.0)
        else:
            plan = unequal_plan(rng)
        cfg, recorded = drawn_twin(rng, refs, args.b_scale)
        s = simulate_session(plan, cfg, seed=args.seed + i)
        s = replace(s, station=recorded)
        r = identify(s)
        b = seed000_budget(s, r, {}, scaled, timer_rows=False)
        err = r.values - truth
        u, U = b.standard_uncertainty(), b.expanded_uncertainty()
        z_u.append(err / u)
        z_a.append(err / r.sigmas)
        cover.append(np.abs(err) <= U)
        cover_a.append(np.abs(err) <= 1.96 * r.sigmas)
        dofs.append(b.effective_dof())
        mu_rej.append(not r.reliable)
        if args.design == "unequal":
            eq = identify(s, weighting="equal")
            z_eq.append((eq.values - truth) / eq.sigmas)
    wall = time.perf_counter() - t0
    z_u, z_a, cover, cover_a, dofs = map(np.array, (z_u, z_a, cover, cover_a, dofs))
    print(f"design {args.design}, {args.n} sessions, Type B scale {args.b_scale:g}, {wall:.0f} s on this machine")
    print(f"eq. 28 rejections (mu >= mu_c): {np.mean(mu_rej):.3f}\n")
    head = "| coefficient | mean z | spread z | nu_eff (median) | coverage of U (k from t) | coverage of 1.96 u_A |"
    if args.design == "unequal":
        head += " spread z, equal weights |"
    print(head)
    print("|---" * (7 if args.design == "unequal" else 6) + "|")
    for j, n in enumerate(NAMES):
        line = (f"| {n} | {z_u[:, j].mean():+.3f} | {z_u[:, j].std(ddof=1):.3f} | {np.median(dofs[:, j]):.1f} | "
                f"{cover[:, j].mean():.3f} | {cover_a[:, j].mean():.3f} |")  # fmt: skip
        if args.design == "unequal":
            line += f" {np.array(z_eq)[:, j].std(ddof=1):.3f} |"
        print(line)
    half = 1.96 * math.sqrt(0.95 * 0.05 / args.n)
    print(f"\n(binomial 95 % half-width of a coverage of 0.95 over {args.n} sessions: {half:.3f})")


if __name__ == "__main__":
    main()
