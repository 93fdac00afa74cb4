"""Monte Carlo of simulated seed-000 sessions: honesty of sigma_k and baseline vs integral errors.

For N sessions of the embedded default twin (rate noise 1e-6 rad/s, jitter
1e-7 s, 50 ns tick): the mean and spread of (k_hat - k)/sigma_k for the
integral method (joint fit), for OLS on Y (the seed's eqs. 20-22 taken
literally), and the RMS-error ratio baseline/integral on the same sessions.
Session k has seed 10000 + k, whatever the executor: the figures are the same
on one core, a local pool or a dask cluster (station/fanout.py); with
--results each session's errors are logged as it finishes and a rerun resumes.

Which simulation path (`--path`):
- `engine` (the default): each session is integral_precession.toml's full session through the engine on the
  deterministic station (config/stations/vibration-sim.toml: drivers against their emulators, in each worker process;
  tests/engine_sessions.py), about 16 s of CPU a session, so N defaults to 40. This is the procedure's
  behaviour: the window phases are the ones the station's timeline gives (on the deterministic station nearly
  the same for every seed), which the baseline method's error depends on.
- `shortcut`: the session_sim shortcut (not the engine): station.twin.session_sim, each window's crank phase drawn
  uniformly, 60 s between windows; 0.1 s of CPU a session, N defaults to 1000. An identification study of the
  estimators over random phases; tests/test_simulation_paths.py holds it statistically equal to the engine
  (per-point residuals, coefficients, residual sigma).

    .venv/bin/python bench/bench_calibration_mc.py [N] [--path engine|shortcut] [--executor local|dask]
        [--scheduler ADDRESS] [--workers W] [--results CASES.jsonl]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from procedures.integral_precession.identify import design, identify
from station.fanout import add_executor_options, run_cases, spec_from_args
from station.twin.config import default_twin
from station.twin.plan import seed000_plan
from station.twin.session_sim import simulate_session

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from engine_sessions import engine_session  # the engine path, shared with the test of both paths

NAMES = ("kzz", "ky", "k3")
SEED0 = 10_000


def ols_on_y(session, truth):
    rates, index, L, _, vib = design(session)
    static = {int(i): r for i, r, v in zip(index, rates, vib, strict=True) if not v}
    Y = np.array([r - static[int(i)] for i, r, v in zip(index, rates, vib, strict=True) if v])
    X = L[vib]
    K, *_ = np.linalg.lstsq(X, Y, rcond=None)
    e = Y - X @ K
    sk = np.sqrt(np.diag(np.linalg.inv(X.T @ X))) * math.sqrt(e @ e / (len(Y) - X.shape[1]))
    return [(K[i] - truth[n]) / sk[i] for i, n in ((1, "kzz"), (2, "ky"), (3, "k3"))]


def one_session(case: tuple[str, int]) -> dict[str, list[float]]:
    """Errors of session k (seed SEED0 + k) by `path`: z of the integral method and of OLS on Y, errors of both."""
    path, k = case
    cfg = default_twin()
    ins = cfg.instrument
    truth = {"kz": ins.kz, "kzz": ins.kzz, "ky": ins.ky, "k3": ins.k3}
    if path == "engine":
        s = engine_session({}, seed=SEED0 + k)
    else:
        s = simulate_session(seed000_plan(), cfg, seed=SEED0 + k)
    ri, rb = identify(s, "integral"), identify(s, "baseline")
    return {
        "z_int": [(ri.coefficient(m)[0] - truth[m]) / ri.coefficient(m)[1] for m in NAMES],
        "z_ols": ols_on_y(s, truth),
        "e_int": [ri.coefficient(m)[0] - truth[m] for m in NAMES],
        "e_base": [rb.coefficient(m)[0] - truth[m] for m in NAMES],
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("n", nargs="?", type=int, help="sessions (default 40 through the engine, 1000 by the shortcut)")
    p.add_argument("--path", choices=("engine", "shortcut"), default="engine",
                   help="engine: through the engine on the deterministic station (default); shortcut: the "
                   "session_sim shortcut")  # fmt: skip
    add_executor_options(p)
    args = p.parse_args(argv)
    n = args.n if args.n is not None else (40 if args.path == "engine" else 1000)
    spec = spec_from_args(args)
    t0 = time.perf_counter()
    rows = run_cases(one_session, [(args.path, k) for k in range(n)], spec, results=args.results,
                     settings={"bench": "calibration_mc", "seed0": SEED0, "path": args.path})  # fmt: skip
    z_int, z_ols, e_int, e_base = (np.array([r[key] for r in rows]) for key in ("z_int", "z_ols", "e_int", "e_base"))
    how = "through the engine on the deterministic station" if args.path == "engine" else "the session_sim shortcut"
    print(f"{n} sessions of 40 points {how} in {time.perf_counter() - t0:.1f} s ({spec.kind}, "
          f"{spec.scheduler or f'{spec.n_workers} workers'})\n")  # fmt: skip
    print(
        "| coefficient | integral: mean z | integral: spread z | OLS on Y: spread z | RMS error integral | "
        "RMS error baseline | baseline / integral | baseline mean error |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for i, m in enumerate(NAMES):
        rms_i = math.sqrt(np.mean(e_int[:, i] ** 2))
        rms_b = math.sqrt(np.mean(e_base[:, i] ** 2))
        print(
            f"| {m} | {z_int[:, i].mean():+.3f} | {z_int[:, i].std(ddof=1):.3f} | {z_ols[:, i].std(ddof=1):.3f} | "
            f"{rms_i:.2e} | {rms_b:.2e} | {rms_b / rms_i:.1f} | {e_base[:, i].mean():+.2e} |"
        )


if __name__ == "__main__":
    main()
