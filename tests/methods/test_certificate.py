"""The calibration certificate (issue 15): conformity rule, instrument file, ISO/IEC 17025 7.8 content, PDF pages.

The seed-000 analysis of a simulated session must give the result JSON of issue 15 (per coefficient
value, unit, u, nu_eff, k, p, U; covariance; budget rows; provenance) and write an HTML and a PDF
certificate whose every page says SIMULATED and carries its page number.
"""

from __future__ import annotations

import io
import json
import math
import re
from pathlib import Path

import numpy as np
import pypdf
import pytest
import scipy.stats

from procedures.common.certificate import (
    CertificateError,
    Limit,
    conformity,
    gum_round,
    load_instrument_spec,
    load_laboratory,
    unit_text,
)
from procedures.common.session_certificate import customer
from procedures.integral_precession.budget import found_none_params
from procedures.integral_precession.procedure import analyse_integral, analyse_multi_frequency
from station.cli.cli import main
from station.jsonsafe import json_safe
from station.twin.config import default_twin
from station.twin.plan import multiposition_plan, seed000_plan
from station.twin.session_sim import simulate_session

PROVENANCE = {"simulated": True, "station_id": "sim-test", "instrument_serial": "SIM-PIGA-0001", "seed": 3,
              "created_utc": "2026-12-01T20:00:00+00:00", "software_version": "0.1.0+gtest", "operator": "tester",
              "host": "ci"}  # fmt: skip


def test_guarded_acceptance_rule() -> None:
    lim = Limit("kzz", -2e-5, 2e-5, "rad/s/g^2")
    assert conformity(1e-5, 5e-6, lim) == "conforms"
    assert conformity(1.8e-5, 5e-6, lim) == "not decided"  # inside, but within U of the limit
    assert conformity(2.2e-5, 5e-6, lim) == "not decided"  # outside, but within U
    assert conformity(3e-5, 5e-6, lim) == "does not conform"
    assert conformity(-3e-5, 5e-6, lim) == "does not conform"
    assert conformity(0.0, 1.0, None) == "no limit"


@pytest.mark.parametrize(
    ("value", "expanded", "printed"),
    [
        (0.5608048, 3.49e-3, ("5.608e-01", "3.5e-03")),
        (1.23456e-6, 9.96e-7, ("1.2e-06", "1.0e-06")),  # U rounds up a decade: the value follows it
        (0.0099996, 2.5e-5, ("1.0000e-02", "2.5e-05")),  # the value rounds up a decade
        (-0.00049, 0.00051, ("-4.9e-04", "5.1e-04")),
        (3e-12, 2.5e-8, ("0.0e-08", "2.5e-08")),  # a value far below U: U's exponent
        (12345.678, 0.95, ("1.234568e+04", "9.5e-01")),
    ],
)
def test_values_are_rounded_to_the_two_significant_digits_of_u(value, expanded, printed) -> None:
    assert gum_round(value, expanded) == printed


def test_a_dimensionless_unit_says_so() -> None:
    assert unit_text("1") == unit_text("") == "(dimensionless)" and unit_text("rad/s/g") == "rad/s/g"


def test_instrument_file_is_checked(tmp_path: Path) -> None:
    spec = load_instrument_spec()
    assert set(spec.limits) >= {"kz", "kzz", "ky", "k3"} and "U" in spec.decision_rule  # and seed 003's static terms
    bad = tmp_path / "bad.toml"
    bad.write_text('[decision_rule]\ntext = "x"\n[limits.kzz]\nmin = 1.0\nmax = -1.0\n')
    with pytest.raises(CertificateError, match=r"\[limits\.kzz\] min = 1\.0, max = -1\.0: expected finite numbers"):
        load_instrument_spec(bad)
    bad.write_text("[limits.kzz]\nmin = 1.0\nmax = 2.0\n")
    with pytest.raises(CertificateError, match=r"decision_rule.*must be stated"):
        load_instrument_spec(bad)


@pytest.fixture(scope="module")
def analysis():
    s = simulate_session(seed000_plan(), default_twin(), seed=3)
    s.meta.update({"store_uid": "t15-int", "params": {}, "procedure": "integral_precession",
                   "provenance": PROVENANCE})  # fmt: skip
    return s, analyse_integral(s)


def test_result_json_has_gum_fields_covariance_budget_and_provenance(analysis) -> None:
    _, a = analysis
    doc = json.loads(json.dumps(json_safe(a.results)))  # what the store keeps
    r = doc["integral"]
    for name in ("kz", "kzz", "ky", "k3"):
        c = r["coefficients"][name]
        assert c["unit"].startswith("rad/s/g")
        assert c["coverage_probability"] == 0.95
        # k is Student's t at the coefficient's effective dof times its shape factor (1 unless rectangular rows,
        # here the unmeasured Zs1 and axs1, flatten the tails), U = k u
        t = scipy.stats.t.ppf(0.975, c["effective_dof"])
        assert c["coverage_factor"] == pytest.approx(t * c["shape_factor"], rel=1e-9)
        assert c["expanded_uncertainty"] == pytest.approx(c["coverage_factor"] * c["standard_uncertainty"])
        assert c["standard_uncertainty"] >= c["sigma"] > 0  # Type B only adds
    cov = np.array(r["covariance"]["matrix"])
    assert r["covariance"]["names"] == ["kz", "kzz", "ky", "k3"]
    np.testing.assert_allclose(cov, cov.T, rtol=0, atol=1e-30)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [r["coefficients"][n]["standard_uncertainty"]
                                                       for n in ("kz", "kzz", "ky", "k3")], rtol=1e-9)  # fmt: skip
    sources = {b["source"]: b for b in r["budget"]}
    assert [b["type"] for b in r["budget"]].count("A") == 1
    for needle in ("Zs1 at 10 Hz, not measured", "axs1", "eps_f", "A0", "local gravity", "latitude", "timer resolution",
                   "latency", "second harmonic Zs2", "second harmonic Zc2"):  # fmt: skip
        assert any(needle in k for k in sources), needle
    for b in r["budget"]:
        assert set(b) >= {"source", "type", "value", "standard_uncertainty", "sensitivity", "contribution"}
        assert set(b["contribution"]) == {"kz", "kzz", "ky", "k3"}
        # one distribution: the shape the budget uses is the one its note states (the timer row said both)
        stated = re.search(r"\b(rectangular|normal)\b", b["note"])
        assert stated is None or stated[1] == b["distribution"], b["source"]
    prov = r["provenance"]
    assert prov["session_uid"] == "t15-int" and prov["instrument_serial"] == "SIM-PIGA-0001"
    assert prov["station_id"] == "sim-test" and prov["software_version"] == "0.1.0+gtest"
    assert prov["operator"] == "tester" and prov["created_utc"].startswith("2026-12-01")
    assert "eq. 21" in r["sigma_Y_eq21_is"] and "one measured rate" in r["sigma_residual_is"]


def _no_nan(text: str) -> None:
    assert "nan" not in text.lower().replace("nanos", ""), "a nan reached the report"


def test_certificate_html_has_clause_7_8_content(analysis) -> None:
    _, a = analysis
    names = sorted(a.files)
    assert names == ["certificate-t15-int.html", "certificate-t15-int.pdf"]
    html = a.files["certificate-t15-int.html"].decode()
    for needle in ("Calibration certificate", "CERT-t15-int", "sim-test", "SIM-PIGA-0001", "integral_precession",
                   "0.1.0+gtest", "tester", "Calibration and environmental conditions", "not measured", "Decision rule",
                   "ILAC-G8", "Traceability", "gravity survey", "counter time base", "Uncertainty budget",
                   "Signatures", "counter(page)", "SIMULATED", "Welch-Satterthwaite", "Residuals", "<svg"):  # fmt: skip
        assert needle in html, needle
    for verdict in ("conforms",):
        assert verdict in html
    _no_nan(html)
    _no_nan(a.report_html)


def test_the_certificate_states_the_conditions_and_cites_the_paper_in_full(analysis) -> None:
    _, a = analysis
    reader = pypdf.PdfReader(io.BytesIO(a.files["certificate-t15-int.pdf"]))
    text = " ".join(" ".join(page.extract_text() for page in reader.pages).split())
    assert "indexing head positions 10: 0, 36, 72, 108, 144, 180, 216, 252, 288, 324 deg" in text
    assert "vibration table 8, 9, 10 Hz at amplitude A0 = 30 mm; 10 static windows (table at rest)" in text
    assert re.search(r"measurement windows Tm 40 windows, 5\d\d\.\d to 5\d\d\.\d s", text)
    assert "seed 000: C. Sun, S.-q. Ren, J.-w. Cao, R. Huo: Integral precession calibration method of PIGA" in text
    assert "seed 001" not in text  # only the papers the certificate names


def test_every_value_u_and_limit_of_the_json_is_whole_on_one_line_of_the_pdf(analysis) -> None:
    """A quality manager reads the PDF: each coefficient's value and U as GUM 7.2.6 rounds them and its limits
    stand unbroken on a line; no dimensionless number carries the unit '1'; no instruction to a developer."""
    _, a = analysis
    reader = pypdf.PdfReader(io.BytesIO(a.files["certificate-t15-int.pdf"]))
    text = "\n".join(page.extract_text() for page in reader.pages).replace("\xa0", " ")
    spec = load_instrument_spec()
    for name, c in json.loads(json.dumps(json_safe(a.results)))["integral"]["coefficients"].items():
        value, big_u = gum_round(c["value"], c["expanded_uncertainty"])
        lim = spec.limits[name]
        for number in (value, big_u, f"[{lim.min:.4g}, {lim.max:.4g}]"):
            assert re.search(rf"(?m)^{re.escape(number)}$", text), (name, number)
    assert not re.search(r"(?m)\d 1$", text) and "set [laboratory]" not in text


def test_certificate_pdf_says_simulated_on_every_page(analysis, tmp_path: Path) -> None:
    _, a = analysis
    pdf = a.files["certificate-t15-int.pdf"]
    assert pdf.startswith(b"%PDF")
    reader = pypdf.PdfReader(io.BytesIO(pdf))
    pages = [page.extract_text() for page in reader.pages]
    text = "\f".join(pages)
    assert len(pages) >= 2
    for i, page in enumerate(pages, 1):
        assert "SIMULATED" in page, f"page {i} does not say SIMULATED"
        assert f"page {i} of {len(pages)}" in page
    _no_nan(text)


def test_multi_frequency_flags_too_few_dof_and_quotes_t_based_u() -> None:
    s = simulate_session(multiposition_plan([0.0, 45.0, 180.0], [8.0, 9.0, 10.0], 560.0), default_twin(), seed=8)
    # the error-source experiments found no table error: the fit's 5 dof dominate every coefficient
    s.meta.update({"store_uid": "t15-mf", "params": found_none_params(), "provenance": PROVENANCE})
    a = analyse_multi_frequency(s)
    r = a.results["integral"]
    assert r["dof"] == 5 and r["few_dof"] == ["kz", "kzz", "ky", "k3"]
    for c in r["coefficients"].values():
        # 5 <= nu_eff < 10 (Type B inputs add dof-free variance): k between t_95(10) = 2.228 and t_95(5) = 2.571
        assert 2.228 < c["coverage_factor"] <= 2.571 + 1e-3
        assert math.isclose(c["expanded_uncertainty"], c["coverage_factor"] * c["standard_uncertainty"])
    assert "few dof" in a.summary
    assert "fewer than 10 effective degrees of freedom" in a.report_html
    assert "Few degrees of freedom" in a.files["certificate-t15-mf.html"].decode()


@pytest.mark.parametrize("positions", [[0.0, 180.0], [0.0, 120.0, 240.0], [0.0, 60.0, 180.0, 300.0]])
def test_self_alignment_report_has_no_nan(positions) -> None:
    """Eq. 26 (two positions) and eq. 25 with no residual dof (three) cannot estimate every sigma: said, not nan."""
    from procedures.integral_precession.procedure import analyse_alignment
    from station.twin.plan import PointSpec, preset_pulses

    plan = [PointSpec(p, 0.0, preset_pulses(p, 560.0)) for p in positions]
    s = simulate_session(plan, default_twin(), seed=1)
    s.meta["params"] = {"kz_radps_per_g": 0.56, "sigma_kz": 1e-4, "sigma_latitude_deg": 0.1}
    a = analyse_alignment(s)
    _no_nan(a.report_html)
    _no_nan(a.summary)
    k0 = a.results["alignment"]["k0"]
    if len(positions) == 3:
        assert k0["sigma"] is None and "not estimable" in k0["note"]
    else:
        assert k0["sigma"] > 0


def test_environment_comes_from_the_stations_sensors_where_it_has_them() -> None:
    from dataclasses import replace

    from procedures.common.session_certificate import environment_conditions

    s = simulate_session(multiposition_plan([0.0, 180.0], [10.0], 560.0), default_twin(), seed=2)
    assert "not measured" in dict(environment_conditions(s))["temperature"]
    pts = [replace(p, extra={"temperature_c": f"{20.0 + 0.1 * i:.1f}"}) for i, p in enumerate(s.points)]
    env = dict(environment_conditions(replace(s, points=pts)))
    assert env["temperature"].startswith("20.00 to 20.30 °C (4 readings")


def test_a_real_stations_certificate_needs_its_laboratory_and_customer(analysis, tmp_path: Path) -> None:
    """The shipped laboratory file names no laboratory: a simulated certificate says SIMULATED LABORATORY, a real
    one is refused in one line naming the file and the key, never a placeholder printed on it."""
    with pytest.raises(CertificateError) as refused:
        load_laboratory(simulated=False)
    assert "\n" not in str(refused.value)
    assert re.fullmatch(r"laboratory file \S*laboratory\.toml: \[laboratory\] name is not set: .*", str(refused.value))
    lab = tmp_path / "laboratory.toml"
    lab.write_text('[laboratory]\nname = "Gyro Lab"\naddress = "1 Main St"\nplace_of_calibration = "room 12"\n')
    assert load_laboratory(simulated=False, path=lab) == {
        "name": "Gyro Lab",
        "address": "1 Main St",
        "place_of_calibration": "room 12",
        "accreditation": "",
    }
    s, a = analysis
    real = dict(PROVENANCE, simulated=False, instrument_serial="PIGA-0042")
    s.meta["provenance"] = real
    try:
        refused = analyse_integral(s)  # analysed and reported all the same; the certificate says why not
        assert not [f for f in refused.files if f.startswith("certificate-")]
        assert "<table" in refused.report_html and "kzz" in refused.results["integral"]["coefficients"]
        why_not = [line for line in refused.summary.splitlines() if line.startswith("no certificate: ")]
        assert len(why_not) == 1 and re.search(r"laboratory\.toml: \[laboratory\] name is not set", why_not[0])
        with pytest.raises(CertificateError, match=r"provenance\.customer is not set: .*--customer NAME\)$"):
            customer(s, simulated=False)
        assert customer(s, simulated=True).startswith("SIMULATED CUSTOMER")
    finally:
        s.meta["provenance"] = PROVENANCE
    html = a.files["certificate-t15-int.html"].decode()
    assert "SIMULATED LABORATORY" in html and "SIMULATED CUSTOMER" in html and "set [laboratory]" not in html


def test_operator_customer_and_duration_from_the_command_line_are_on_the_certificate(tmp_path: Path, capsys) -> None:
    proc = tmp_path / "quick.toml"
    proc.write_text('procedure = "integral_precession"\n[params]\npositions_deg = [0, 72, 144, 216, 288]\n'
                    "freqs_hz = [9, 10]\nwindow_s = 5\nsettle_s = 0\n")  # fmt: skip
    out = tmp_path / "out"
    main(["run", str(proc), "--out", str(out), "--seed", "4", "--operator", "Q. Manager", "--customer", "ACME Gyro"])
    (cert,) = out.glob("certificate-*.pdf")
    text = "\n".join(page.extract_text() for page in pypdf.PdfReader(cert).pages)
    assert re.search(r"(?m)^operator\s*\nQ\. Manager$", text) and re.search(r"(?m)^\s*customer\s*\nACME Gyro$", text)
    console = re.search(r"(?m)^finished: (\d+\.\d\d h of station time \(15 points\)) in ", capsys.readouterr().out)
    assert console and f"duration of the measurements\n{console[1]}\n" in text  # one duration, console and certificate
