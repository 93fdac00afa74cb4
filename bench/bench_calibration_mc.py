"""Monte Carlo of simulated seed-000 sessions: honesty of sigma_k and baseline vs integral errors.

For N sessions of the embedded default twin (rate noise 1e-6 rad/s, jitter
1e-7 s, 50 ns tick): the mean and spread of (k_hat - k)/sigma_k for the
integral method (joint fit), for OLS on Y (the seed's eqs. 20-22 taken
literally), and the RMS-error ratio baseline/integral on the same sessions.

    .venv/bin/python bench/bench_calibration_mc.py [N]
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from methods.seed000.identify import design, identify
from models.config import default_twin
from models.plan import seed000_plan
from models.session_sim import simulate_session

NAMES = ("kzz", "ky", "k3")


def ols_on_y(session, truth):
    rates, index, L, _, vib = design(session)
    static = {int(i): r for i, r, v in zip(index, rates, vib, strict=True) if not v}
    Y = np.array([r - static[int(i)] for i, r, v in zip(index, rates, vib, strict=True) if v])
    X = L[vib]
    K, *_ = np.linalg.lstsq(X, Y, rcond=None)
    e = Y - X @ K
    sk = np.sqrt(np.diag(np.linalg.inv(X.T @ X))) * math.sqrt(e @ e / (len(Y) - X.shape[1]))
    return [(K[i] - truth[n]) / sk[i] for i, n in ((1, "kzz"), (2, "ky"), (3, "k3"))]


def main(n: int) -> None:
    cfg = default_twin()
    k = cfg.instrument
    truth = {"kz": k.kz, "kzz": k.kzz, "ky": k.ky, "k3": k.k3}
    z_int, z_ols, e_int, e_base = [], [], [], []
    t0 = time.perf_counter()
    for seed in range(n):
        s = simulate_session(seed000_plan(), cfg, seed=10_000 + seed)
        ri, rb = identify(s, "integral"), identify(s, "baseline")
        z_int.append([(ri.coefficient(m)[0] - truth[m]) / ri.coefficient(m)[1] for m in NAMES])
        e_int.append([ri.coefficient(m)[0] - truth[m] for m in NAMES])
        e_base.append([rb.coefficient(m)[0] - truth[m] for m in NAMES])
        z_ols.append(ols_on_y(s, truth))
    z_int, z_ols, e_int, e_base = map(np.array, (z_int, z_ols, e_int, e_base))
    print(f"{n} sessions of 40 points in {time.perf_counter() - t0:.1f} s\n")
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
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1000)
