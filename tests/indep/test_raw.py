"""Raw records as written: grating samples follow the motion formula, pulse edges end at Tm."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from indep.cases import make_case

A0 = 0.03


def _points(d: Path) -> dict[str, dict]:
    with (d / "points.csv").open() as fh:
        return {r["point_id"]: r for r in csv.DictReader(fh)}


def _fit(t: np.ndarray, z: np.ndarray, w: float, harmonics: int) -> tuple[np.ndarray, np.ndarray]:
    cols = [np.ones_like(t)]
    for j in range(1, harmonics + 1):
        cols += [np.sin(j * w * t), np.cos(j * w * t)]
    X = np.stack(cols, axis=1)
    beta = np.linalg.lstsq(X, z, rcond=None)[0]
    return beta, z - X @ beta


def test_grating_record_is_the_motion_plus_stated_noise(tmp_path: Path) -> None:
    """Null: z = zbar + A0 sin psi + noise (fitted phase); residual rms is the stated noise (chi^2)."""
    truth = make_case(90, "null", tmp_path / "n", raw=True)
    pts = _points(tmp_path / "n")
    noise = truth["noise"]["grating_noise_m"]
    sd = math.sqrt(noise**2 + 1e-9**2 / 12)  # 1 nm steps
    n_vib = 0
    for f in sorted((tmp_path / "n" / "raw").glob("*.npz")):
        rec, row = np.load(f), pts[f.stem]
        t, z = rec["grating_t"], rec["grating_z"]
        assert np.allclose(np.diff(t), 1 / 5000.0, rtol=1e-6)
        if row["kind"] == "static":
            assert np.std(z) < 5 * sd
            continue
        n_vib += 1
        beta, res = _fit(t, z, 2 * math.pi * float(row["freq_hz"]), 3)
        amp = math.hypot(beta[1], beta[2])
        assert abs(amp - A0) < 6 * sd * math.sqrt(2 / t.size)
        assert math.hypot(beta[3], beta[4]) < 6 * sd * math.sqrt(2 / t.size)  # no 2nd harmonic in a null
        q = float(np.sum((res / sd) ** 2))
        dof = t.size - beta.size
        assert chi2.ppf(1e-4, dof) < q < chi2.ppf(1 - 1e-4, dof)
    assert n_vib >= 1


def test_grating_record_shows_the_waveform_harmonics(tmp_path: Path) -> None:
    truth = make_case(91, "waveform_harmonics", tmp_path / "h", snr=30.0, raw=True)
    p = truth["params"]["waveform_harmonics"]
    pts = _points(tmp_path / "h")
    sd = truth["noise"]["grating_noise_m"]
    for f in sorted((tmp_path / "h" / "raw").glob("*.npz")):
        rec, row = np.load(f), pts[f.stem]
        if row["kind"] == "static":
            continue
        t, z = rec["grating_t"], rec["grating_z"]
        beta, _ = _fit(t, z, 2 * math.pi * float(row["freq_hz"]), 3)
        tol = 6 * sd * math.sqrt(2 / t.size) + 1e-9
        assert abs(math.hypot(beta[3], beta[4]) - math.hypot(p["zs2_m"], p["zc2_m"])) < tol
        assert abs(math.hypot(beta[5], beta[6]) - math.hypot(p["zs3_m"], p["zc3_m"])) < tol


def test_pulse_edges_and_reference_stamps_agree_with_points_csv(tmp_path: Path) -> None:
    """Edges never pass Tm; a stretch at the window's end closes on Tm; reference stamps are T apart."""
    ended_at_tm = 0
    for seed in (92, 93, 94):
        truth = make_case(seed, "null", tmp_path / f"s{seed}", raw=True)
        sig_t = truth["noise"]["timing_sigma_s"]
        slack = 6 * sig_t + 2 * 5e-8
        pts = _points(tmp_path / f"s{seed}")
        for f in sorted((tmp_path / f"s{seed}" / "raw").glob("*.npz")):
            rec, row = np.load(f), pts[f.stem]
            tm = float(row["Tm_s"])
            pt = rec["pulse_t"]
            assert pt.size > 100 and pt[-1] <= tm + slack
            if "pulse_dir" in rec.files:
                assert set(np.unique(rec["pulse_dir"])) <= {-1, 1}
            if abs(pt[-1] - tm) <= slack:
                ended_at_tm += 1
            if row["kind"] == "vibration" and "reference_t" in rec.files and rec["reference_t"].size > 2:
                period = 1 / float(row["freq_hz"])
                assert np.allclose(np.diff(rec["reference_t"]), period, atol=slack + 1e-4 * period)
                # t1 of points.csv is on the same grid of crossings: (ref - t1) / T is whole
                k = (rec["reference_t"] - float(row["t1_s"])) / period
                assert np.allclose(k, np.round(k), atol=(slack + 1e-3 * period) / period)
    assert ended_at_tm >= 1
