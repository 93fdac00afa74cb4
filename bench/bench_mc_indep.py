"""Coverage of the seed-000 expanded uncertainty on sessions this project's twin did not make (issue 15, d7).

Sessions from the independent generator (tests/indep: physics.md implemented again, numerically, with
random designs of four families, random instruments far from seed 000's, and random noise that is either a
stated per-window repeatability or white noise over windows of different length) are written as
piga-session/1 directories, read back by station.interchange, identified (weighted joint least squares)
and budgeted (procedures.integral_precession.budget, the default references). Per coefficient: mean and spread of
(k_hat - k) / u_c and the coverage of U (target 0.93-0.97).

    .venv/bin/python bench/bench_mc_indep.py [N]

Simulation path: neither the engine nor session_sim: tests/indep's independent generator.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from indep.generator import FAMILIES, Truth, random_coefficients, random_design, random_noise, write_session

from procedures.integral_precession.budget import seed000_budget
from procedures.integral_precession.identify import identify
from station.interchange import read_session
from station.least_squares import FitError

NAMES = ("kz", "kzz", "ky", "k3")


def main(n: int) -> None:
    rng = np.random.default_rng(15)
    z, cover, dofs, skipped = [], [], [], 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            design = random_design(rng, FAMILIES[i % len(FAMILIES)])
            co = random_coefficients(rng)
            truth = Truth(co, noise=random_noise(rng))
            path = Path(tmp) / f"s{i}"
            write_session(path, design, truth, rng)
            session = read_session(path)
            try:
                r = identify(session)
            except FitError:
                skipped += 1  # a drawn design that cannot separate the coefficients (refused by name)
                continue
            b = seed000_budget(session, r, {}, timer_rows=False)
            err = r.values - np.array([co.kz, co.kzz, co.ky, co.k3])
            z.append(err / b.standard_uncertainty())
            cover.append(np.abs(err) <= b.expanded_uncertainty())
            dofs.append(r.dof)
    z, cover, dofs = np.array(z), np.array(cover), np.array(dofs)
    print(f"{len(z)} independent sessions ({skipped} refused as singular) in {time.perf_counter() - t0:.0f} s; "
          f"fit dof {dofs.min()}-{dofs.max()} (median {np.median(dofs):.0f})\n")  # fmt: skip
    print("| coefficient | mean z | spread z | coverage of U | coverage of U, dof < 20 |")
    print("|---|---:|---:|---:|---:|")
    low = dofs < 20
    for j, name in enumerate(NAMES):
        small = f"{cover[low, j].mean():.3f} ({int(low.sum())})" if low.any() else "none"
        print(f"| {name} | {z[:, j].mean():+.3f} | {z[:, j].std(ddof=1):.3f} | {cover[:, j].mean():.3f} | {small} |")
    print(f"\n(binomial half-width at 0.95 over {len(z)}: {1.96 * math.sqrt(0.0475 / max(len(z), 1)):.3f})")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 200)
