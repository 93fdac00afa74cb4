"""Coverage of the seed-000 expanded uncertainty on sessions this project's twin did not make (issue 15, d7).

Sessions from the independent generator (tests/indep: physics.md implemented again, numerically, with
random designs of four families, random instruments far from seed 000's, and random noise that is either a
stated per-window repeatability or white noise over windows of different length) are written as
piga-session/1 directories, read back by station.interchange, identified (weighted joint least squares)
and budgeted (procedures.integral_precession.budget, the default references; the sessions have no table errors,
so their params say the error-source experiments found none: found_none_params). Per coefficient: mean and
spread of (k_hat - k) / u_c and the coverage of U (target 0.93-0.97).

    .venv/bin/python bench/bench_mc_indep.py [N]                      # N sessions of the four random families
    .venv/bin/python bench/bench_mc_indep.py --matrix [N] [--quick] [--corpus DIR] [--jobs 2]
        [--type-a | --true-form | --form-note] [--cells 3,19]

--matrix (issue 32): equal-angle designs of 6, 10 and 16 positions at 8, 9, 10 Hz x rate noise constant per
window (stated as instrument_repeatability_radps, or not), white, or mixed (half each at 300 s; neither is ever
stated) x unequal windows (50 revolutions each) or equal ones (every nominal Tm 200 s); each cell's sessions
drawn from its own seed (rng [32, cell]), so runs before and after a change see the same sessions; --corpus keeps
them (DIR/cellNN/sK, generated once, extended when N grows) for re-scoring; --type-a scores the fit's own
uncertainty (z = err / sigma, t at the fit dof) without the budget's refits; --true-form scores, Type A, the fit
with the generator's own form's weights (what knowing the form gives, the reference for a chosen form). Each cell
prints coverage / sd z (sd of z's normal scores, Phi^-1(F_t(z; nu)): 1 for a right u at any dof, where sd z itself
is sqrt(nu / (nu - 2))). --form-note: per cell and coefficient, the share of sessions whose identification names
the coefficient in its note on the noise form's choice (u FORM_NOTE_RATIO times the chosen form's or more), and the
Type A coverage of U in those sessions / in the others.

Simulation path: neither the engine nor session_sim: tests/indep's independent generator.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from indep.generator import (
    FAMILIES,
    Noise,
    Truth,
    equal_angle_design,
    random_coefficients,
    random_design,
    random_noise,
    write_session,
)

from procedures.integral_precession.budget import found_none_params, seed000_budget
from procedures.integral_precession.identify import FORM_NOTE_RATIO, design, identify, point_weights
from station.interchange import read_session
from station.least_squares import FitError, fit_joint

NAMES = ("kz", "kzz", "ky", "k3")
MATRIX_POSITIONS = (6, 10, 16)
MATRIX_NOISE = (("constant", "per_window", True), ("constant", "per_window", False), ("white", "white", False),
                ("mixed", "mixed", False))  # fmt: skip
MATRIX_WINDOWS = (("unequal", None), ("equal", 200.0))
QUICK_PER_CELL = 20


def score(path: Path, k_true: np.ndarray, type_a: bool = False, true_form: str | None = None):
    """Read back, identify and budget one session: (z, covered, fit dof, the normal score of each z), or None if
    refused as singular. `type_a`: the fit's own uncertainty only (z = err / sigma, U = t(fit dof) sigma), no budget;
    `true_form` (the generator's rate_form): Type A of the fit with that form's weights, what knowing the form gives.
    The normal score Phi^-1(F_t(z; nu)) at each coefficient's dof (nu_eff of the budget) has sd 1 whatever nu
    when u is right: z itself is Student's t, whose sd is sqrt(nu / (nu - 2)) (1.08 at 14 dof)."""
    session = read_session(path)
    try:
        r = identify(session)
    except FitError:
        return None  # a drawn design that cannot separate the coefficients (refused by name)
    err = r.values - k_true
    if true_form is not None:
        var = np.array([Noise(1.0, true_form, 0.0, 0.0).rate_sd(p.Tm_s) ** 2 for p in session.points])
        rates, index, L, names, _vib = design(session)
        fit = fit_joint(rates, index, L, names, weights=1.0 / var)
        return type_a_score(fit.values - k_true, fit.sigmas, fit.dof)
    if type_a:
        return type_a_score(err, r.sigmas, r.dof)
    b = seed000_budget(session, r, found_none_params(), timer_rows=False)
    z = err / b.standard_uncertainty()
    return z, np.abs(err) <= b.expanded_uncertainty(), r.dof, normal_score(z, b.effective_dof())


def form_note_score(path: Path, k_true: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Whether identify's note on the noise form names each coefficient (its u FORM_NOTE_RATIO times the chosen
    fit's or more) and whether U (Type A) covers it; None if refused as singular."""
    session = read_session(path)
    try:
        r = identify(session)
    except FitError:
        return None
    weights, _ = point_weights(session)
    chosen = fit_joint(*design(session)[:4], weights=weights)
    named = np.sqrt(np.diag(r.cov) / np.diag(chosen.cov)) >= FORM_NOTE_RATIO
    return named, type_a_score(r.values - k_true, r.sigmas, r.dof)[1]


def form_note_row(corpus: Path, per_cell: int, cell: tuple) -> str:
    """One cell's --form-note row: per coefficient, share named: coverage named / not named."""
    number, n_pos, label, form, stated, windows, window_s = cell
    scored = [
        form_note_score(path, k) for path, k in cell_corpus(corpus, number, n_pos, form, stated, window_s, per_cell)
    ]
    named, cover = (np.array(x) for x in zip(*[s for s in scored if s is not None], strict=True))

    def part(j: int) -> str:
        rates = [f"{cover[m, j].mean():.3f}" if m.any() else "-" for m in (named[:, j], ~named[:, j])]
        return f"{named[:, j].mean():.2f}: {rates[0]} / {rates[1]}"

    return (
        f"| {n_pos} | {label} | {'yes' if stated else 'no'} | {windows} | {len(named)} | "
        + " | ".join(part(j) for j in range(len(NAMES)))
        + " |"
    )


def type_a_score(err: np.ndarray, sigmas: np.ndarray, dof: int):
    """score's tuple for a fit's own uncertainty: z = err / sigma, U = t(dof) sigma."""
    z = err / sigmas
    return z, np.abs(err) <= stats.t.ppf(0.975, dof) * sigmas, dof, normal_score(z, np.full(z.size, dof))


def normal_score(z: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """Phi^-1(F_t(z; dof)): a Student's t variable made standard normal (infinite dof: z itself)."""
    return stats.norm.ppf(stats.t.cdf(z, np.minimum(dof, 1e6)))


def main(n: int) -> None:
    rng = np.random.default_rng(15)
    z, cover, dofs, skipped = [], [], [], 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            design = random_design(rng, FAMILIES[i % len(FAMILIES)])
            truth = Truth(random_coefficients(rng), noise=random_noise(rng))
            write_session(Path(tmp) / f"s{i}", design, truth, rng)
            co = truth.co
            out = score(Path(tmp) / f"s{i}", np.array([co.kz, co.kzz, co.ky, co.k3]))
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


def cell_corpus(
    root: Path, cell: int, n_pos: int, form: str, stated: bool, window_s: float | None, per_cell: int
) -> list:
    """The cell's first `per_cell` sessions as (directory, true kz, kzz, ky, k3), generated once under
    root/cellNN/sK from rng [32, cell] (state.json keeps the rng between runs, so a larger N extends the corpus
    with the very sessions a single run would draw)."""
    folder = root / f"cell{cell:02d}"
    state_file = folder / "state.json"
    rng = np.random.default_rng([32, cell])
    truths: list = []
    if state_file.exists():
        state = json.loads(state_file.read_text())
        rng.bit_generator.state, truths = state["rng"], state["truths"]
    design = equal_angle_design(n_pos, (8.0, 9.0, 10.0), window_revs=50, window_s=window_s)
    while len(truths) < per_cell:
        truth = Truth(random_coefficients(rng), noise=replace(random_noise(rng), rate_form=form))
        write_session(folder / f"s{len(truths)}", design, truth, rng, state_noise=stated)
        truths.append([truth.co.kz, truth.co.kzz, truth.co.ky, truth.co.k3, truth.noise.rate_sigma_radps])
        state_file.write_text(json.dumps({"rng": rng.bit_generator.state, "truths": truths}))
    return [(folder / f"s{i}", np.array(t[:4])) for i, t in enumerate(truths[:per_cell])]


def matrix_cells() -> list[tuple[int, int, str, str, bool, str, float | None]]:
    """(cell number, positions, noise label, generator form, stated, windows label, equal window) of every cell."""
    cells = []
    for n_pos in MATRIX_POSITIONS:
        for label, form, stated in MATRIX_NOISE:
            for windows, window_s in MATRIX_WINDOWS:
                cells.append((len(cells) + 1, n_pos, label, form, stated, windows, window_s))
    return cells


def selected_cells(only: set[int] | None) -> list[tuple[int, int, str, str, bool, str, float | None]]:
    """The matrix's cells whose numbers are in `only` (None: every cell)."""
    return [c for c in matrix_cells() if only is None or c[0] in only]


def form_note_matrix(per_cell: int, corpus: Path, jobs: int, only: set[int] | None = None) -> None:
    """--form-note: per cell and coefficient, the share of sessions the note names it in, and U's coverage there
    and elsewhere (`form_note_row`)."""
    print("| positions | rate noise | stated | windows | n | " + " | ".join(NAMES) + " |")
    print("|---:|---|---|---|---:|" + "---|" * len(NAMES))
    with ProcessPoolExecutor(jobs) as pool:
        for row in pool.map(partial(form_note_row, corpus, per_cell), selected_cells(only)):
            print(row, flush=True)


def cell_row(
    corpus: Path, per_cell: int, type_a: bool, true_form: bool, cell: tuple
) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """One cell scored: its table row, and z, covered and z's normal score per session and coefficient."""
    number, n_pos, label, form, stated, windows, window_s = cell
    z, cover, dofs, scores = [], [], [], []
    for path, k_true in cell_corpus(corpus, number, n_pos, form, stated, window_s, per_cell):
        out = score(path, k_true, type_a, form if true_form else None)
        if out is not None:
            z.append(out[0])
            cover.append(out[1])
            dofs.append(out[2])
            scores.append(out[3])
    cov_j, sd_j, sd_n = np.mean(cover, axis=0), np.std(z, axis=0, ddof=1), np.std(scores, axis=0, ddof=1)
    cells = " | ".join(f"{c:.3f} / {s:.2f} ({n:.2f})" for c, s, n in zip(cov_j, sd_j, sd_n, strict=True))
    row = (
        f"| {n_pos} | {label} | {'yes' if stated else 'no'} | {windows} | {len(z)} | {int(np.median(dofs))} | {cells} |"
    )
    return row, np.array(z), np.array(cover), np.array(scores)


def matrix(
    per_cell: int, corpus: Path, jobs: int, type_a: bool, true_form: bool = False, only: set[int] | None = None
) -> None:
    """Coverage of U and spread of z per coefficient in every cell of designs x noise forms x windows (`only`: the
    cells of these numbers), the cells' sessions generated once under `corpus` and scored in `jobs` processes
    (`type_a`: of the fit's own uncertainty; `true_form`: of the fit with the true form's weights)."""
    t0 = time.perf_counter()
    heads = " | ".join(f"{c} cov / sd z (sd score)" for c in NAMES)
    print(f"| positions | rate noise | stated | windows | n | dof | {heads} |")
    print("|---:|---|---|---|---:|---:|" + "---:|" * len(NAMES))
    cov, sd, sd_n, n, z_all, cover_all = [], [], [], [], [], []
    with ProcessPoolExecutor(jobs) as pool:
        for row, z, cover, scores in pool.map(
            partial(cell_row, corpus, per_cell, type_a, true_form), selected_cells(only)
        ):
            print(row, flush=True)
            cov.append(cover.mean(axis=0))
            sd.append(z.std(axis=0, ddof=1))
            sd_n.append(scores.std(axis=0, ddof=1))
            n.append(len(z))
            z_all.append(z)
            cover_all.append(cover)
    cov, sd, sd_n = np.array(cov), np.array(sd), np.array(sd_n)
    # a cell's coverage beyond the binomial 95 % band about 0.95 at its n, a normal score's sd beyond the band about 1
    # (sd of a sample sd of N(0, 1): 1 / sqrt(2 (n - 1))): more than sampling explains
    beyond = np.abs(cov - 0.95) > 1.96 * np.sqrt(0.0475 / np.array(n))[:, None]
    beyond_sd = np.abs(sd_n - 1.0) > 1.96 / np.sqrt(2.0 * (np.array(n) - 1))[:, None]
    z_all, cover_all = np.vstack(z_all), np.vstack(cover_all)
    pooled = ", ".join(f"{c} {cover_all[:, j].mean():.3f} / {z_all[:, j].std(ddof=1):.2f}" for j, c in enumerate(NAMES))
    print(f"\nall {len(z_all)} sessions pooled (coverage / sd z): {pooled}")
    print(f"cells x coefficients outside coverage 0.93-0.97: {int(np.sum((cov < 0.93) | (cov > 0.97)))} of {cov.size}, "
          f"beyond the binomial 95 % band about 0.95: {int(beyond.sum())}; sd z outside 0.9-1.1: "
          f"{int(np.sum((sd < 0.9) | (sd > 1.1)))}; sd of the normal scores outside 0.9-1.1: "
          f"{int(np.sum((sd_n < 0.9) | (sd_n > 1.1)))}, beyond its 95 % band about 1: "
          f"{int(beyond_sd.sum())}")  # fmt: skip
    half = 1.96 * math.sqrt(0.0475 / per_cell)
    cpu = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        use = resource.getrusage(who)
        cpu += use.ru_utime + use.ru_stime
    print(f"coverage {cov.min():.3f}-{cov.max():.3f}, sd z {sd.min():.2f}-{sd.max():.2f} over "
          f"all cells; binomial half-width at 0.95 over {per_cell}: {half:.3f}, sd z's about "
          f"{1.96 / math.sqrt(2 * (per_cell - 1)):.2f}; {time.perf_counter() - t0:.0f} s, CPU {cpu:.0f} s")  # fmt: skip


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("n", nargs="?", type=int, help="sessions (per cell with --matrix; default 200)")
    parser.add_argument("--matrix", action="store_true", help="the issue 32 matrix of designs x noise x windows")
    parser.add_argument("--quick", action="store_true", help=f"--matrix with {QUICK_PER_CELL} sessions per cell")
    parser.add_argument("--corpus", type=Path, help="--matrix: the folder of the cells' sessions (default: a temp)")
    parser.add_argument("--type-a", action="store_true", help="--matrix: Type A only (the fit's sigma, t at its dof)")
    parser.add_argument(
        "--true-form", action="store_true", help="--matrix: Type A with the true form's weights (knowing the form)"
    )
    parser.add_argument("--jobs", type=int, default=1, help="--matrix: processes scoring cells (default 1)")
    parser.add_argument(
        "--form-note", action="store_true", help="--matrix: who the noise form's note names, and U's coverage there"
    )
    parser.add_argument(
        "--cells", help="--matrix: only these cells, numbered 1-24 in the table's order, comma-separated (default all)"
    )
    a = parser.parse_args()
    only = None if a.cells is None else {int(c) for c in a.cells.split(",")}
    if a.matrix:
        per_cell = QUICK_PER_CELL if a.quick else a.n or 200
        with tempfile.TemporaryDirectory() as tmp:
            corpus = a.corpus or Path(tmp)
            if a.form_note:
                form_note_matrix(per_cell, corpus, a.jobs, only)
            else:
                matrix(per_cell, corpus, a.jobs, a.type_a, a.true_form, only)
    else:
        main(a.n or 200)
