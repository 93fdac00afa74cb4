"""Every method's analysis writes a calibration certificate (issue 15, ISO/IEC 17025 7.8): seeds 001-004.

Each method's simulated session is made from its twin path (no station: seconds, not minutes), stamped with a
simulated provenance and analysed by the procedure's own analyse(), as station.cli.analysis_job runs it. Its files
must be
certificate-<uid>.html and .pdf; the certificate must state every headline coefficient of the results JSON with
the same value, U and k, the conformity of each under the stated decision rule, the traceability of the method's
own references, the environment (or "not measured"), the budget tables and figures, the signatures; every PDF
page must say SIMULATED and "page i of n"; no "nan" anywhere.

The certificate prints U and u to two significant digits, the value to U's last decimal place (GUM 7.2.6) and k
with 2 decimals: the numbers read back must equal the JSON's within half a unit of the last printed digit; every
value, U and limit must stand whole on one line of the PDF's text.
"""

from __future__ import annotations

import io
import math
import re
import sys
from dataclasses import replace
from html import unescape
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pypdf
import pytest

from procedures.common.certificate import CONDITIONS, fmt_dof, gum_round, unit_text
from procedures.common.papers import PAPERS
from procedures.common.references import load_references
from station.engine.registry import Analysis

ROOT = Path(__file__).parents[2]
sys.path.insert(0, str(ROOT / "bench"))
import bench_mc_methods as mc  # noqa: E402  (the four-pose windows of seed 003's design, as the bench makes them)

pytestmark = pytest.mark.timeout(120)
PROVENANCE = {"simulated": True, "station_id": "sim-cert", "seed": 5, "created_utc": "2026-12-02T08:00:00+00:00",
              "software_version": "0.1.0+gcert", "operator": "tester", "host": "ci"}  # fmt: skip
CONFORMITY = {"conforms", "does not conform", "not decided (U straddles the limit)"}
REFS = load_references()


def _stamp(session, uid: str, serial: str, procedure: str, params: dict | None = None):
    session.meta.update({"store_uid": uid, "procedure": procedure, "params": params or {},
                         "provenance": PROVENANCE | {"instrument_serial": serial}})  # fmt: skip
    return session


# ---------------------------------------------------------------- sessions of each method


def seed001_analysis() -> Analysis:
    from procedures.tumble.procedure import analyse
    from procedures.tumble.tumble_session import tumble_session
    from station.twin.pendulous_accelerometer import AccelerometerModel

    session, _ = tumble_session(AccelerometerModel(), [20.0, 80.0, -40.0, 20.0], 1, 8e-6, np.random.default_rng(4))
    return analyse(_stamp(session, "c001", "SIM-ACC-0001", "tumble"))


def seed002_analysis() -> Analysis:
    """Nine calibration runs (60 s at rest, 30 s of vibration: short for the test) reduced as the procedure does."""
    from procedures.rlg_g_sensitivity.analysis import RunRecord, observation_values, observe_run
    from procedures.rlg_g_sensitivity.report import analyse_session
    from procedures.rlg_g_sensitivity.vibration_run import simulate_run
    from station.constants import G_MPS2
    from station.session import Measurement, Session, StationInfo
    from station.twin.fixture_poses import CALIBRATION_POSES, POSES
    from station.twin.shaker_motion import sine_drive
    from station.twin.strapdown_imu import Site, StrapdownImuTwin

    st = StationInfo()
    site = Site(st.g_mps2, st.earth_rate_radps, st.latitude_rad)
    rng = np.random.default_rng(6)
    runs = []
    for k in CALIBRATION_POSES:
        r = simulate_run(StrapdownImuTwin(), site, POSES[k], sine_drive(20.0, 1.5, G_MPS2), rate_hz=200.0,
                         align_s=60.0, vibrate_s=30.0, ramp_s=2.0, rng=rng)  # fmt: skip
        rec = RunRecord.from_times(r.dtheta, r.dv, r.dt_s, 0.0, r.t0_s, r.tk_s)
        snippet = {"snippet_rate_radps": (r.dtheta[-100:] / r.dt_s).tolist(),
                   "snippet_force_mps2": (r.dv[-100:] / r.dt_s).tolist()}  # fmt: skip
        values = {"role": "calibration", "pose": k, "rate_hz": 200, "align_s": 60.0, **snippet}
        values |= observation_values(observe_run(rec, site))
        runs.append(Measurement(f"cal{k:02d}-pose{k}", "seed002_run", values))
    session = Session(st, [], measurements=runs)
    return analyse_session(_stamp(session, "c002", "SIM-IMU-0001", "rlg_g_sensitivity"))


def seed003_session():
    """Both PIGAs' four-pose windows and A's two calibration sequences (22 positions each) of the seed-003 twin,
    as the gravity-field procedure stores them (points tagged dut, setup, pose, block), with A on the head zero."""
    from drivers.second_instrument.emulator import static_rates_radps
    from procedures.multiposition.gravity_field import ALIGNMENT, CALIBRATION
    from procedures.multiposition.sequences import SCHEMES, sequence_deg
    from station.session import Measurement, PointRecord, Session
    from station.twin.config import TwinConfig

    twin = TwinConfig.from_toml(ROOT / "config" / "twins" / "multiposition.toml").with_effect("mount_misalignment",
                                                                                  dtheta_mount=0.0)  # fmt: skip
    rng, ppr, noise = np.random.default_rng(5), twin.station.pulses_per_rev, 2e-7
    windows = [(w.instrument, w.setup, w.pose, w.theta_rad, w.rate_radps, "four_pose")
               for w in mc.four_pose_windows(twin, rng, noise)]  # fmt: skip
    for scheme in SCHEMES:
        head = np.radians(sequence_deg(scheme, 22))
        pose, rates = static_rates_radps(twin, 1, head)["A"]
        rates = rates + rng.normal(0.0, noise, head.size)
        windows += [("A", 1, pose, h, r, CALIBRATION + scheme) for h, r in zip(head, rates, strict=True)]
    points = []
    for i, (dut, setup, pose, head, rate, block) in enumerate(windows):
        pulses = int(math.copysign(5 * ppr, rate))  # 10 pi per window; Tm such that the rate is the twin's
        tags = {"dut": dut, "setup": str(setup), "pose": str(pose), "block": block}
        tm_s = 2 * math.pi * pulses / (ppr * rate)
        point = PointRecord(f"w{i:03d}", i, 100.0 * i, math.degrees(head), 0.0, "static", pulses, tm_s, extra=tags)
        points.append(point)
    align = [Measurement(f"align-{s}", ALIGNMENT, {"setup": s, "round": 1, "misalignment_rad": 0.0, "sigma_rad": 8e-6,
                                                   "k0+ky_radps": 4e-4, "zero_before_deg": 0.0, "zero_deg": 0.0})
             for s in (1, 2)]  # fmt: skip
    return Session(twin.station, points, measurements=align)


def seed003_analysis() -> Analysis:
    from procedures.multiposition.procedure import analyse_gravity_field

    params = {"model": "seed003", "harmonics": 3}
    return analyse_gravity_field(_stamp(seed003_session(), "c003", "SIM-PIGA-0001", "multiposition", params))


def seed004_analysis() -> Analysis:
    """Six sweep offsets, the best offset and after the removal (half the quadratic term, as a removal leaves it),
    each a 0/180/60 deg x 8/9/10 Hz calibration of the seed-004 float model's kzz at that offset."""
    from procedures.nonlinear_suppression.analysis import AFTER_REMOVAL, AT_BEST, SWEEP, servo_offset_measurement
    from procedures.nonlinear_suppression.procedure import analyse_suppression, sweep_prefix
    from station.session import Session
    from station.twin import nonlinear_error as ne
    from station.twin.config import default_twin
    from station.twin.plan import multiposition_plan
    from station.twin.session_sim import simulate_session

    kz, twin = 0.56, default_twin()
    model = ne.FloatModel.seed004(kz)
    plan = multiposition_plan([0.0, 180.0, 60.0], [8.0, 9.0, 10.0], 560.0)
    groups = [(sweep_prefix(i), SWEEP, x, 1.0) for i, x in enumerate([-2.0, -1.5, -1.0, -0.5, 0.0, 0.5])]
    groups += [("B", AT_BEST, -0.85, 1.0), ("A", AFTER_REMOVAL, -0.85, 0.5)]
    points, measurements = [], []
    for j, (prefix, stage, offset, left) in enumerate(groups):
        kzz = left * float(model.kzz_radps_per_g2(offset * ne.ARCSEC_RAD, kz))
        cfg = replace(twin, instrument=replace(twin.instrument, kz=kz, kzz=kzz, ky=0.0, k3=0.0))
        s = simulate_session(plan, cfg, seed=300 + j)
        measurements.append(servo_offset_measurement(f"offset-{j}", prefix, stage, offset))
        points += [replace(p, point_id=f"{prefix}-{p.point_id}") for p in s.points]
    session = Session(s.station, points, measurements=measurements)
    return analyse_suppression(_stamp(session, "c004", "SIM-PIGA-0001", "nonlinear_suppression"))


# ---------------------------------------------------------------- what the results JSON says


def headline(method: str, results: dict) -> dict[str, dict]:
    """Certificate row name -> the JSON's GUM entry of each headline coefficient."""
    if method == "001":
        return {f"{n} at T{t['block'] + 1} {t['setpoint_c']:g} °C": c for t in results["eight_point"]["temperatures"]
                for n, c in t["coefficients"].items()}  # fmt: skip
    if method == "002":
        return {f"tau_{n}": c for n, c in results["flexure"]["gum"]["coefficients"].items()}
    if method == "003":
        names = {"uncompensated": "without compensation", "compensated_total": "with compensation"}
        return {f"{n} ({scheme}, {text})": c for scheme, cal in results["gravity_field"]["calibration"].items()
                for fit, text in names.items() for n, c in cal[fit]["coefficients"].items()}  # fmt: skip
    return dict(results["suppression"]["gum"]["coefficients"])


class _Rows(HTMLParser):
    """The cells of every table row of the HTML certificate, each with the heading (h2) of its section."""

    def __init__(self) -> None:
        super().__init__()
        self.section, self.in_heading, self.rows, self.cell = "", False, [], None

    def handle_starttag(self, tag, attrs) -> None:
        if tag == "h2":
            self.in_heading, self.section = True, ""
        elif tag == "tr":
            self.rows.append((self.section, []))
        elif tag in ("td", "th"):
            self.cell = ""

    def handle_endtag(self, tag) -> None:
        if tag == "h2":
            self.in_heading = False
        elif tag in ("td", "th") and self.cell is not None:
            self.rows[-1][1].append(self.cell.strip())
            self.cell = None

    def handle_data(self, data) -> None:
        if self.cell is not None:
            self.cell += data
        elif self.in_heading:
            self.section += data


def result_cells(html: str) -> dict[str, list[str]]:
    parser = _Rows()
    parser.feed(html)
    return {cells[0]: cells for section, cells in parser.rows if section.startswith("4.") and cells[0] != "coefficient"}


ANALYSES = {"001": seed001_analysis, "002": seed002_analysis, "003": seed003_analysis, "004": seed004_analysis}
REFERENCES = {
    "001": ("tumble_head_angle_rad", "voltmeter_gain", "voltmeter_offset_v", "chamber_temperature_c"),
    "002": ("imu_accel_scale", "imu_gyro_bias_radps", "imu_clock_rel", "latitude_deg", "imu_gyro_scale"),
    "003": ("index_harmonic_rad", "latitude_deg", "timer_resolution_s"),
    "004": ("g_mps2", "A0_m", "angular_momentum_kgm2ps", "end_radius_mm", "removal_angle_deg"),
}
NOT_RUN = {"004": ("zs1_z0_m", "axs1_rad", "eps_f")}  # experiments the session did not run: never cited
CONDITION_SHOWN = {"001": "optical head positions", "002": "latitude", "003": "indexing head positions",
                   "004": "Hz at amplitude A0 = 30 mm"}  # fmt: skip
NOT_THEIRS = {"001": "imu_gyro_scale", "002": "angular_momentum_kgm2ps", "003": "voltmeter_gain",
              "004": "tumble_head_angle_rad"}  # fmt: skip


@pytest.fixture(scope="module", params=sorted(ANALYSES))
def analysed(request):
    import json

    from station.jsonsafe import json_safe

    a = ANALYSES[request.param]()
    return request.param, a, json.loads(json.dumps(json_safe(a.results)))  # the results as the store keeps them


def _no_nan(text: str, where: str) -> None:
    assert "nan" not in text.lower().replace("nanos", ""), f"a nan reached the {where}"


def test_the_analysis_returns_the_certificate_files(analysed) -> None:
    method, a, _ = analysed
    assert sorted(a.files) == [f"certificate-c{method}.html", f"certificate-c{method}.pdf"]
    assert a.files[f"certificate-c{method}.pdf"].startswith(b"%PDF")


def test_the_html_states_every_headline_coefficient_with_the_jsons_value_u_and_k(analysed) -> None:
    method, a, results = analysed
    html = a.files[f"certificate-c{method}.html"].decode()
    rows = result_cells(html)
    expected = headline(method, results)
    assert set(rows) == set(expected)
    for name, c in expected.items():
        _, value, unit, u, nu, k, big_u, limit, verdict = rows[name]
        # GUM 7.2.6: U (and u) to two significant digits, the value to U's last decimal place
        assert re.fullmatch(r"\d\.\de[-+]\d\d", big_u) and re.fullmatch(r"\d\.\de[-+]\d\d", u), (name, big_u, u)
        assert float(big_u) == pytest.approx(c["expanded_uncertainty"], rel=0.05), name
        last_place = 10.0 ** (int(big_u.split("e")[1]) - 1)
        assert abs(float(value) - c["value"]) <= 0.5 * last_place * (1 + 1e-9), name
        assert float(value) != 0.0 or abs(c["value"]) <= 0.5 * last_place, name
        assert unit == unit_text(c["unit"]) and unit != "1"
        assert nu == fmt_dof(math.inf if c["effective_dof"] is None else c["effective_dof"])
        assert float(u) == pytest.approx(c["standard_uncertainty"], rel=0.05), name
        assert float(k) == pytest.approx(c["coverage_factor"], abs=5e-3), name
        assert c["expanded_uncertainty"] == pytest.approx(c["coverage_factor"] * c["standard_uncertainty"])
        assert verdict in CONFORMITY if limit != "none" else verdict == "no limit", (name, limit, verdict)
    assert any(cells[-1] in CONFORMITY for cells in rows.values())  # some coefficient is judged against a limit


def test_the_html_has_what_clause_7_8_asks(analysed) -> None:
    method, a, _ = analysed
    html = a.files[f"certificate-c{method}.html"].decode()
    for needle in ("Calibration certificate", f"CERT-c{method}", "sim-cert", "0.1.0+gcert", "tester",
                   "1. Identification", "2. Dates", "2026-12-02", CONDITIONS, "Decision rule",
                   "ILAC-G8", "5. Traceability", "6. Uncertainty budget", "Figures", "<svg", "Signatures",
                   "counter(page)", "SIMULATED", "Welch-Satterthwaite", "JCGM 101"):  # fmt: skip
        assert needle in html, needle
    text = unescape(html)
    for key in REFERENCES[method]:
        assert REFS[key].traceability in text, key
    for key in NOT_RUN.get(method, ()):
        assert REFS[key].traceability not in text, key
    assert REFS[NOT_THEIRS[method]].quantity not in text  # the method's own references only
    assert f"seed {method}: {PAPERS[method]}" in text  # the method's paper cited in full
    env = html.split(CONDITIONS)[1].split("4. Results")[0]
    assert ("°C (chamber product sensor" in env) if method == "001" else ("not measured" in env)
    assert CONDITION_SHOWN[method] in env and "site" in env  # the calibration conditions beside the environment
    _no_nan(html, "certificate")
    _no_nan(a.report_html, "report")
    _no_nan(a.summary, "summary")


def test_every_pdf_page_says_simulated_and_its_number_and_states_the_results(analysed) -> None:
    method, a, results = analysed
    reader = pypdf.PdfReader(io.BytesIO(a.files[f"certificate-c{method}.pdf"]))
    pages = [page.extract_text() for page in reader.pages]
    assert len(pages) >= 2
    for i, page in enumerate(pages, 1):
        assert "SIMULATED" in page, f"page {i} does not say SIMULATED"
        assert f"page {i} of {len(pages)}" in page
    text = "\n".join(pages).replace("\xa0", " ")
    for name, c in headline(method, results).items():
        # each printed number whole on one line: value, U and the limits (no "[-2e-05, / 2e-05]")
        for number in gum_round(c["value"], c["expanded_uncertainty"]):
            assert re.search(rf"(?m)(^|\s){re.escape(number)}(\s|$)", text), (name, number)
    for limit in {row[7] for row in result_cells(a.files[f"certificate-c{method}.html"].decode()).values()}:
        assert re.search(rf"(?m)^{re.escape(limit.replace(chr(0xA0), ' '))}$", text), limit
    assert not re.search(r"(?m)\d 1$", text), "a dimensionless number printed with unit '1'"
    assert "Decision rule" in text and "Signatures" in text
    _no_nan(text, "PDF")


def test_limits_of_each_headline_coefficient_are_in_its_instrument_file() -> None:
    """Every coefficient whose limit the certificate names is judged against the file's numbers."""
    from procedures.common.certificate import load_instrument_spec

    files = {"001": ("accelerometer-sim.toml", {"K1", "k0", "k2", "k3", "delta_o", "delta_ip"}),
             "002": ("imu-sim.toml", {"tau"}), "003": ("piga-sim.toml", {"k0+ky", "kz", "kzz-ky", "koq"}),
             "004": ("piga-suppressed-sim.toml", {"K2"})}  # fmt: skip
    for name, limits in files.values():
        spec = load_instrument_spec(ROOT / "config" / "instruments" / name)
        assert limits <= set(spec.limits), name
        assert "U" in spec.decision_rule
