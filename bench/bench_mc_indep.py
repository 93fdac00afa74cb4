"""Coverage of the seed-000 expanded uncertainty on sessions this project's twin did not make (issue 15, d7).

Sessions from the independent generator (tests/indep: physics.md implemented again, numerically, with
random designs of four families, random instruments far from seed 000's, and random noise that is either a
stated per-window repeatability or white noise over windows of different length) are written as
piga-session/1 directories, read back by station.interchange, identified (weighted joint least squares)
and budgeted (procedures.integral_precession.budget, the default references). Per coefficient: mean and spread of
(k_hat - k) / u_c and the coverage of U (target 0.93-0.97).

    .venv/bin/python bench/bench_mc_indep.py [N]                      # N sessions of the four random families
    .venv/bin/python bench/bench_mc_indep.py --matrix [N] [--quick]   # N sessions per cell (--quick: 20)

--matrix (issue 32): equal-angle designs of 6, 10 and 16 positions at 8, 9, 10 Hz x rate noise constant per
window (stated as instrument_repeatability_radps, or not), white, or mixed (half each at 300 s; neither is ever
stated) x unequal windows (50 revolutions each) or equal ones (every nominal Tm 200 s); each cell's sessions
drawn from its own seed, so runs before and after a change see the same sessions.

Simulation path: neither the engine nor session_sim: tests/indep's independent generator.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from indep.generator import (
    FAMILIES,
    Design,
    Truth,
    equal_angle_design,
    random_coefficients,
    random_design,
    random_noise,
    write_session,
)

from procedures.integral_precession.budget import seed000_budget
from procedures.integral_precession.identify import identify
from station.interchange import read_session
from station.least_squares import FitError

NAMES = ("kz", "kzz", "ky", "k3")
MATRIX_POSITIONS = (6, 10, 16)
MATRIX_NOISE = (("constant", "per_window", True), ("constant", "per_window", False), ("white", "white", False),
                ("mixed", "mixed", False))  # fmt: skip
MATRIX_WINDOWS = (("unequal", None), ("equal", 200.0))
QUICK_PER_CELL = 20


def score(path: Path, design: Design, truth: Truth, rng: np.random.Generator, stated: bool = True):
    """Write, read back, identify and budget one session: (z, covered, fit dof), or None if refused as singular."""
    write_session(path, design, truth, rng, state_noise=stated)
    session = read_session(path)
    try:
        r = identify(session)
    except FitError:
        return None  # a drawn design that cannot separate the coefficients (refused by name)
    b = seed000_budget(session, r, {}, timer_rows=False)
    co = truth.co
    err = r.values - np.array([co.kz, co.kzz, co.ky, co.k3])
    return err / b.standard_uncertainty(), np.abs(err) <= b.expanded_uncertainty(), r.dof


def main(n: int) -> None:
    rng = np.random.default_rng(15)
    z, cover, dofs, skipped = [], [], [], 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            design = random_design(rng, FAMILIES[i % len(FAMILIES)])
            truth = Truth(random_coefficients(rng), noise=random_noise(rng))
            out = score(Path(tmp) / f"s{i}", design, truth, rng)
            if out is None:
                skipped += 1
                continue
            z.append(out[0])
            cover.append(out[1])
            dofs.append(out[2])
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


def matrix(per_cell: int) -> None:
    """Coverage of U and spread of z per coefficient in every cell of designs x noise forms x windows."""
    t0 = time.perf_counter()
    heads = " | ".join(f"{c} cov / sd z" for c in NAMES)
    print(f"| positions | rate noise | stated | windows | n | dof | {heads} |")
    print("|---:|---|---|---|---:|---:|" + "---:|" * len(NAMES))
    worst_cov, worst_sd = [], []
    cell = 0
    with tempfile.TemporaryDirectory() as tmp:
        for n_pos in MATRIX_POSITIONS:
            for label, form, stated in MATRIX_NOISE:
                for windows, window_s in MATRIX_WINDOWS:
                    cell += 1
                    rng = np.random.default_rng([32, cell])
                    design = equal_angle_design(n_pos, (8.0, 9.0, 10.0), window_revs=50, window_s=window_s)
                    z, cover, dofs = [], [], []
                    for i in range(per_cell):
                        noise = replace(random_noise(rng), rate_form=form)
                        truth = Truth(random_coefficients(rng), noise=noise)
                        out = score(Path(tmp) / f"c{cell}s{i}", design, truth, rng, stated)
                        if out is not None:
                            z.append(out[0])
                            cover.append(out[1])
                            dofs.append(out[2])
                    z, cover = np.array(z), np.array(cover)
                    cov_j, sd_j = cover.mean(axis=0), z.std(axis=0, ddof=1)
                    worst_cov += [cov_j.min(), cov_j.max()]
                    worst_sd += [sd_j.min(), sd_j.max()]
                    cells = " | ".join(f"{c:.3f} / {s:.2f}" for c, s in zip(cov_j, sd_j, strict=True))
                    print(f"| {n_pos} | {label} | {'yes' if stated else 'no'} | {windows} | {len(z)} | "
                          f"{int(np.median(dofs))} | {cells} |", flush=True)  # fmt: skip
    half = 1.96 * math.sqrt(0.0475 / per_cell)
    print(f"\ncoverage {min(worst_cov):.3f}-{max(worst_cov):.3f}, sd z {min(worst_sd):.2f}-{max(worst_sd):.2f} over "
          f"all cells; binomial half-width at 0.95 over {per_cell}: {half:.3f}, sd z's about "
          f"{1.96 / math.sqrt(2 * (per_cell - 1)):.2f}; {time.perf_counter() - t0:.0f} s")  # fmt: skip


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if "--matrix" in sys.argv:
        matrix(QUICK_PER_CELL if "--quick" in sys.argv else int(args[0]) if args else 200)
    else:
        main(int(args[0]) if args else 200)
