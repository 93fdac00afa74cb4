"""Seed 000's error-source experiments: the seed's Tables 5-7 through the analyses, and the three
procedures end to end on a simulated station whose twin carries the seed's errors.

(a) the analyses on the seed's own numbers: eq. 32 from Table 5, eq. 31's column, eq. 34 from Table 7;
(b) `integral_precession.parasitic_translation` (Table 5's frequencies, 5 turns each): z0, z1 recovered against
    the twin's eq. 32 (z0 = -1.299e-4 m, z1 = 3.2e-6 m s/rad), Table 5's Zs1 beside them;
(c) `integral_precession.frequency_stability` (Table 6's frequencies, 10 periods each) with eps_f = 1e-6;
(d) `integral_precession.parasitic_rotation` (0.1 Hz, 2 turns, 12 readings a turn) with the twin's parasitic
    rotation set to eq. 34 of Table 7 (ax0 16.579", axs1 -0.921", axc1 0.195").
Each run: the procedure file's parameters, 1000x virtual time, wall time measured.

    .venv/bin/python bench/bench_error_sources.py

Simulation path: through the engine on the deterministic station (controller, engine, drivers, emulators, in this
process).
"""

from __future__ import annotations

import platform
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

from drivers.config import load_station_config
from drivers.station import simulated_station
from procedures.integral_precession.parasitic_rotation import (
    AXES,
    SEED_HARMONICS_ARCSEC,
    TABLE7_ANGLE_DEG,
    TABLE7_ARCSEC,
    fit_at_phases,
    table7_psi_rad,
)
from procedures.integral_precession.table_motion import (
    SEED_TABLE5_M,
    SEED_Z0_M,
    SEED_Z1_M_S_PER_RAD,
    fit_zs1,
    sampling_delay_error_m,
)
from station.cli.controller import StationController
from station.store import SessionStore
from station.twin.config import default_twin
from station.twin.table_tilt import ARCSEC_RAD

ROOT = Path(__file__).resolve().parents[1]
STATION = load_station_config(ROOT / "config" / "stations/gradiometer-sim.toml")
EPS_F = 1e-6


def seed_tables() -> None:
    f = np.array(list(SEED_TABLE5_M))
    zs1 = np.array([v[0] for v in SEED_TABLE5_M.values()])
    line = fit_zs1(2 * np.pi * f, zs1, np.full(f.size, 1.0))  # the seed gives no uncertainties: equal weights
    print("(a) the seed's own tables")
    print(f"eq. 32 from Table 5: z0 = {line.z0_m * 1e3:.5f} mm, z1 = {line.z1_m_s_per_rad * 1e3:.5f} mm s/rad")
    dA = sampling_delay_error_m(f, 0.03)
    print("eq. 31 (mm): " + ", ".join(f"{f_:g} Hz {d * 1e3:.2e}" for f_, d in zip(f, dA, strict=True)))
    for axis in AXES:
        h = fit_at_phases(axis, table7_psi_rad(TABLE7_ANGLE_DEG), TABLE7_ARCSEC[axis])
        seed = SEED_HARMONICS_ARCSEC[axis]
        print(f"eq. 34 from Table 7, {axis}: a0 {h.a0:.3f}, as1 {h.as1:+.3f} ± {h.sigma_as1:.3f}, "
              f"ac1 {h.ac1:+.3f} ± {h.sigma_ac1:.3f} (seed {seed[0]:+.2f}, {seed[1]:+.2f}); "
              f"residual rms {h.residual_rms:.3f}")  # fmt: skip


def run(procedure_file: str, twin, out: Path) -> tuple[dict, float, float]:
    doc = tomllib.loads((ROOT / "config" / "procedures" / procedure_file).read_text())
    with simulated_station(STATION, twin, seed=7, speed=1000.0) as sim, SessionStore(out / "bench.sqlite") as store:
        controller = StationController(sim.devices, store, STATION.station_model(), reports_dir=out)
        t0 = time.perf_counter()
        outcome = controller.run(doc["procedure"], doc["params"])
        wall = time.perf_counter() - t0
        assert outcome.analysis is not None, outcome.faults
        return outcome.analysis.results, wall, controller.engine.progress.elapsed_s


def translation(out: Path) -> None:
    twin = (
        default_twin()
        .with_effect("waveform_fundamental", z0=SEED_Z0_M, z1=SEED_Z1_M_S_PER_RAD)
        .with_effect("waveform_harmonics", Zs2=2.4e-6, Zc2=-4.2e-6)
    )
    r, wall, station = run("integral_precession.parasitic_translation.toml", twin, out)
    r = r["parasitic_translation"]
    fit = r["zs1_fit"]
    print(f"\n(b) parasitic translation: {wall:.1f} s wall, {station:.0f} s station")
    print("| f (Hz) | Zs1 (mm) | σ (mm) | seed Table 5 Zs1 (mm) | Zs2 (mm) | Zc2 (mm) | ΔA_max (mm) |")
    for row in r["table5"]:
        seed = SEED_TABLE5_M[row["commanded_hz"]][0] * 1e3
        print(f"| {row['commanded_hz']:g} | {row['Zs1_m'] * 1e3:.5f} | {row['sigma_Zs1_m'] * 1e3:.1e} | {seed:.4f} "
              f"| {row['Zs2_m'] * 1e3:.5f} | {row['Zc2_m'] * 1e3:.5f} | {row['dA_max_m'] * 1e3:.2e} |")  # fmt: skip
    for name, truth in (("z0_m", SEED_Z0_M), ("z1_m_s_per_rad", SEED_Z1_M_S_PER_RAD)):
        v, s = fit[name], fit[f"sigma_{name}"]
        print(f"{name}: {v:.6e} ± {s:.1e} (injected {truth:.4e}; error {(v - truth) / s:+.2f} σ)")
    print(f"chi2 {fit['chi2']:.2f} for {fit['dof']} dof")


def stability(out: Path) -> None:
    twin = default_twin().with_effect("frequency_error", eps_f=EPS_F)
    r, wall, station = run("integral_precession.frequency_stability.toml", twin, out)
    r = r["frequency_stability"]
    print(f"\n(c) frequency stability: {wall:.1f} s wall, {station:.0f} s station; passed {r['passed']}")
    print("| f (Hz) | f̄ (Hz) | Δf (Hz) | −ε_f f (Hz) | σ_f/f | Δα eq. 33 (rad/s) |")
    for row in r["table6"]:
        f = row["commanded_hz"]
        print(f"| {f:g} | {row['fbar_hz']:.9f} | {row['delta_f_hz']:+.2e} | {-EPS_F * f:+.2e} | {row['stability']:.1e} "
              f"| {row['delta_alpha_radps']:.1e} |")  # fmt: skip
    e = r["eps_f"]
    error = (e["value"] - EPS_F) / e["sigma"]
    print(f"eps_f: {e['value']:.6e} ± {e['sigma']:.1e} (injected {EPS_F:g}; error {error:+.2f} σ)")


def rotation(out: Path) -> None:
    seed = fit_at_phases("x", table7_psi_rad(TABLE7_ANGLE_DEG), TABLE7_ARCSEC["x"])
    a0, as1, ac1 = seed.a0, seed.as1, seed.ac1
    twin = default_twin().with_effect("parasitic_rotation", ax0=a0 * ARCSEC_RAD, axs1=as1 * ARCSEC_RAD,
                                      axc1=ac1 * ARCSEC_RAD)  # fmt: skip
    r, wall, station = run("integral_precession.parasitic_rotation.toml", twin, out)
    r = r["parasitic_rotation"]
    print(f"\n(d) parasitic rotation: {wall:.1f} s wall, {station:.0f} s station")
    print("| ψ (deg) | crank disk (deg) | φx (″) | seed Table 7 φx (″) |")
    seed_rows = {round(a): i for i, a in enumerate(TABLE7_ANGLE_DEG)}
    for row in r["table7"]:
        i = seed_rows.get(round(row["crank_disk_deg"]) % 360)
        seed = f"{TABLE7_ARCSEC['x'][i]:.3f}" if i is not None else ""
        print(f"| {row['psi_deg']:.0f} | {row['crank_disk_deg']:.0f} | {row['phi_x_arcsec']:.3f} | {seed} |")
    x = r["harmonics"]["x"]
    for key, truth in (("ax0", a0), ("axs1", as1), ("axc1", ac1)):
        v, s = x[f"{key}_arcsec"], x[f"sigma_{key}_arcsec"]
        print(f'{key}: {v:+.4f} ± {s:.4f}" (injected {truth:+.4f}; error {(v - truth) / s:+.2f} σ)')
    print(f"eq. 34 on the slot means: {r['eq34_on_slot_means']['x']}")
    print(f"compensation: {r['compensation']}")


def main() -> None:
    print(f"{platform.machine()}, {platform.python_version()}, numpy {np.__version__}")
    seed_tables()
    with tempfile.TemporaryDirectory() as tmp:
        for job in (translation, stability, rotation):
            job(Path(tmp))


if __name__ == "__main__":
    main()
