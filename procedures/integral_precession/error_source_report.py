"""Self-contained HTML reports of seed 000's error-source experiments (6.1.1-6.1.3, Tables 5-7).

Tables in the seed's layout with the uncertainties beside them, and inline SVG plots:
Zs1(w) with its fit (eq. 32) and the harmonic spectrum; sigma_f / f against f;
phi against the crank phase with the fitted harmonics (eq. 34).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np

from procedures.integral_precession.frequency_stability import Table6Row
from procedures.integral_precession.parasitic_rotation import (
    SEED_HARMONICS_ARCSEC,
    TABLE7_ANGLE_DEG,
    TABLE7_ARCSEC,
    RotationHarmonics,
)
from procedures.integral_precession.table_motion import (
    SEED_TABLE5_M,
    SEED_Z0_M,
    SEED_Z1_M_S_PER_RAD,
    Waveform,
    Zs1Line,
    sampling_delay_error_m,
)
from station.htmlkit import document, mapping_table, svg, table

MM = 1e3


def _pm(value: float, sigma: float, scale: float = 1.0, fmt: str = ".5f") -> str:
    return f"{value * scale:{fmt}} ± {sigma * scale:.1e}"


def translation_report(title: str, commanded_hz: Sequence[float], waves: Sequence[Waveform], line: Zs1Line,
                       a0_m: float) -> str:  # fmt: skip
    """Table 5 with uncertainties and the seed's Zs1, Zs1(w) and its fit, the harmonic spectrum, the compensation."""
    n = len(waves[0].zs_m)
    head = ["f (Hz)", "f measured (Hz)", "A_s (mm)", "Zs1 (mm)", "seed Zs1 (mm)", "Zc1 (mm)", "ΔA_max (mm, eq. 31)"]
    head += [f"{k}{j} (mm)" for j in range(2, n + 1) for k in ("Zs", "Zc")]
    rows = []
    for f, w in zip(commanded_hz, waves, strict=True):
        seed = SEED_TABLE5_M.get(float(f))
        row = [f"{f:g}", f"{w.freq_hz:.9f} ± {w.sigma_freq_hz:.1e}", _pm(w.mean_m, w.sigma_mean_m, MM),
               _pm(w.zs_m[0], w.sigma_zs_m[0], MM), f"{seed[0] * MM:.4f}" if seed else "—",
               _pm(w.zc_m[0], w.sigma_zc_m[0], MM),
               f"{float(sampling_delay_error_m(w.freq_hz, a0_m)) * MM:.2e}"]  # fmt: skip
        for j in range(1, n):
            row += [_pm(w.zs_m[j], w.sigma_zs_m[j], MM), _pm(w.zc_m[j], w.sigma_zc_m[j], MM)]
        rows.append(row)
    w_rad = np.array([w.w_radps for w in waves])
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    zs1 = np.array([w.zs_m[0] for w in waves])
    axes[0].errorbar(w_rad, zs1 * MM, yerr=np.array([w.sigma_zs_m[0] for w in waves]) * MM, fmt="o", label="measured")
    seed_f = np.array(list(SEED_TABLE5_M))
    axes[0].plot(2 * np.pi * seed_f, [SEED_TABLE5_M[f][0] * MM for f in seed_f], "x", label="seed 000 Table 5")
    grid = np.linspace(0, w_rad.max() * 1.05, 50)
    axes[0].plot(grid, (line.z0_m + line.z1_m_s_per_rad * grid) * MM, label="fit, eq. 32")
    axes[0].plot(grid, (SEED_Z0_M + SEED_Z1_M_S_PER_RAD * grid) * MM, ls=":", label="seed 000 eq. 32")
    axes[0].set(title="Zs1(ω) (Table 5, eq. 32)", xlabel="ω (rad/s)", ylabel="Zs1 (mm)")
    harmonics = np.arange(1, n + 1)
    for w in waves:
        amp = np.hypot(w.zs_m, w.zc_m)
        axes[1].semilogy(harmonics, np.maximum(amp, 1e-12) * MM, marker="o", label=f"{w.freq_hz:.3g} Hz")
    axes[1].set(title="Harmonics |Zj| beyond A0 (eq. 30)", xlabel="harmonic j", ylabel="mm", xticks=harmonics)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fit = {"z0 (m)": _pm(line.z0_m, line.sigma_z0_m, fmt=".5e"),
           "z1 (m s/rad)": _pm(line.z1_m_s_per_rad, line.sigma_z1_m_s_per_rad, fmt=".5e"),
           "chi2 / dof": f"{line.chi2:.2f} / {line.dof}", "seed 000 eq. 32": "z0 = -1.299e-4 m, z1 = 3.2e-6 m s/rad",
           "compensation": "Compensation(zs1_m=lambda w: z0 + z1 w)"}  # fmt: skip
    parts = [
        "<h2>Parasitic translation (as seed 000 Table 5)</h2>",
        "<p>Harmonics of the grating record relative to the crank phase from the reference crossings, by least "
        "squares on sin/cos j ψ (eq. 30); ΔA_max is the sampling-delay error of eq. 31.</p>",
        table(head, rows),
        "<h2>Zs1(ω) = z0 + z1 ω (eq. 32)</h2>",
        mapping_table(fit),
        svg(fig),
    ]
    return document(title, parts)


def stability_report(
    title: str, rows: Sequence[Table6Row], stability_max: float, eps_f: float, sigma_eps: float
) -> str:
    """Table 6 with the verdict against the specification, and sigma_f / f against f."""
    head = ["f (Hz)", "f̄ (Hz)", "Δf = f − f̄ (Hz)", "σ_f / f", "Δα (rad/s, eq. 33)", f"σ_f / f < {stability_max:g}"]
    body = [[f"{r.commanded_hz:g}", f"{r.fbar_hz:.9f} ± {r.sigma_fbar_hz:.1e}", f"{r.delta_f_hz:+.2e}",
             f"{r.stability:.2e}", f"{r.delta_alpha_radps:.2e}", "pass" if r.passes(stability_max) else "FAIL"]
            for r in rows]  # fmt: skip
    f = np.array([r.commanded_hz for r in rows])
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    axes[0].semilogy(f, np.maximum([r.stability for r in rows], 1e-12), "o-", label="measured")
    axes[0].axhline(stability_max, color="r", ls="--", label="specification (Table 4)")
    axes[0].set(title="Frequency stability σ_f / f", xlabel="f (Hz)")
    axes[1].errorbar(f, [r.delta_f_hz for r in rows], yerr=[r.sigma_fbar_hz for r in rows], fmt="o")
    axes[1].plot(f, -eps_f * f, label=f"−ε_f f, ε_f = {eps_f:.2e}")
    axes[1].set(title="Δf = f − f̄", xlabel="f (Hz)", ylabel="Hz")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    verdict = all(r.passes(stability_max) for r in rows)
    parts = [
        "<h2>Frequency stability (as seed 000 Table 6)</h2>",
        f"<p class={'ok' if verdict else 'bad'}>{'PASS' if verdict else 'FAIL'}: "
        f"σ_f / f against the specification {stability_max:g}; relative frequency error "
        f"ε_f = f̄ / f − 1 = {eps_f:.3e} ± {sigma_eps:.1e}.</p>",
        table(head, body),
        svg(fig),
    ]
    return document(title, parts)


def rotation_report(title: str, fits: Mapping[str, RotationHarmonics], psi_rad: np.ndarray,
                    arrays: Mapping[str, np.ndarray], table7: Sequence[Mapping], by_eq34: Mapping) -> str:  # fmt: skip
    """Table 7 from the series, the harmonics per axis (eq. 34 and least squares), phi against the crank phase."""
    axes_ = list(fits)
    head = ["ψ (deg)", "crank disk angle as Table 7 (deg)", "mean offset from ψ (deg)"]
    head += [f"φ{a} (″)" for a in axes_] + [f"seed Table 7 φ{a} (″)" for a in axes_]
    seed_rows = {round(angle): i for i, angle in enumerate(TABLE7_ANGLE_DEG)}
    body = []
    for r in table7:
        i = seed_rows.get(round(r["crank_disk_deg"]) % 360)
        seed = [f"{TABLE7_ARCSEC[a][i]:.3f}" if i is not None else "" for a in axes_]
        body.append([f"{r['psi_deg']:.0f}", f"{r['crank_disk_deg']:.0f}", f"{r['mean_offset_deg']:+.2f}"]
                    + [f"{r[f'phi_{a}_arcsec']:.3f}" for a in axes_] + seed)  # fmt: skip
    hrows = []
    for a, f in fits.items():
        seed_as1, seed_ac1 = SEED_HARMONICS_ARCSEC.get(a, (np.nan, np.nan))
        e = by_eq34[a]
        hrows.append([a, f"{f.a0:.3f} ± {f.sigma_a0:.3f}", f"{f.as1:+.3f} ± {f.sigma_as1:.3f}",
                      f"{f.ac1:+.3f} ± {f.sigma_ac1:.3f}", f"{e['as1']:+.3f}", f"{e['ac1']:+.3f}",
                      f"{seed_as1:+.2f}, {seed_ac1:+.2f}", f"{f.residual_rms:.4f}"])  # fmt: skip
    fig, ax = plt.subplots(1, len(axes_), figsize=(12, 3.4))
    deg = np.degrees(np.mod(psi_rad, 2 * np.pi))
    grid = np.linspace(0, 2 * np.pi, 200)
    for i, a in enumerate(axes_):
        f = fits[a]
        ax[i].plot(deg, arrays[f"phi_{a}_arcsec"], "o", ms=4, label="readings")
        ax[i].plot(np.degrees(grid), f.a0 + f.as1 * np.sin(grid) + f.ac1 * np.cos(grid), label="fit")
        ax[i].set(
            title=f"φ{a} against the crank phase", xlabel="ψ (deg)", ylabel="arc-seconds", xticks=range(0, 361, 60)
        )
        ax[i].grid(alpha=0.3)
        ax[i].legend(fontsize=8)
    harmonics_head = ["axis", "a0", "as1 (least squares)", "ac1 (least squares)", "as1 (eq. 34)", "ac1 (eq. 34)",
                      "seed 000 (as1, ac1)", "residual rms"]  # fmt: skip
    parts = [
        "<h2>Gradiometer readings by crank phase (as seed 000 Table 7)</h2>",
        "<p>Means over the turns of the readings at ψ = 2πi/N; Table 7's crank disk angle is 90° − ψ "
        "(counted from top dead centre against the crank's turn).</p>",
        table(head, body),
        "<h2>Harmonics a0 + as1 sin ψ + ac1 cos ψ (eq. 34), arc-seconds</h2>",
        table(harmonics_head, hrows),
        f"<p>Compensation of the integral identification: axs1 = {fits['x'].as1:+.4f}″ "
        "(Compensation(axs1_rad=...), in rad in the results).</p>",
        svg(fig),
    ]
    return document(title, parts)
