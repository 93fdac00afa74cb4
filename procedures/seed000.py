"""Seed 000: integral precession calibration of a PIGA on the linear vibration table.

`seed000.integral_precession`: at each indexing position the vibration tests
at every frequency, then the static test (seed 000 5.2), each a counter window
of whole precession revolutions lasting about `window_s`; identified by the
integral method (exact window means) and by the integer periodic vibration
baseline (eq. 35) on the same data.
"""

from __future__ import annotations

from station.analysis.identify import METHODS, identify
from station.engine.params import Param
from station.engine.registry import Analysis, procedure
from station.engine.steps import Checkpoint, MeasurePoint, Note
from station.plan import SEED000_FREQS_HZ, SEED000_WINDOW_S, equal_angle_positions_deg, multiposition_plan, point_id
from station.report import render_report
from station.session import Session

POSITION_PARAMS = (
    Param("positions_deg", list, default=equal_angle_positions_deg(10), min=-360.0, max=360.0, unit="deg",
          help="indexing positions (seed 000: 10 equal angles)"),
    Param("freqs_hz", list, default=list(SEED000_FREQS_HZ), min=0.1, max=10.0, unit="Hz",
          help="vibration frequencies at every position"),
    Param("window_s", float, default=SEED000_WINDOW_S, min=1.0, max=100_000.0, unit="s",
          help="target window length: the preset is the whole revolutions that take about this long"),
    Param("settle_s", float, default=5.0, min=0.0, max=600.0, unit="s", help="settling after each change"),
    Param("raw", bool, default=False, help="record raw streams (every pulse edge, grating stretch)"),
)  # fmt: skip


def analyse_integral(session: Session) -> Analysis:
    """Both identifications (seed 000 eqs. 19-22 and 35) and the session report."""
    results = {m: identify(session, m) for m in METHODS}
    uid = session.meta.get("store_uid", "")
    html = render_report(session, results, title=f"Session {uid}: integral precession (seed 000)")
    lines = []
    for m, r in results.items():
        coefs = ", ".join(f"{n} = {v:.6e} ± {s:.1e}" for n, v, s in zip(r.names, r.values, r.sigmas, strict=True))
        lines.append(f"{m}: {coefs}; sigma = {r.sigma_residual:.3e} rad/s, mu = {r.mu:.2f} (mu_c = {r.mu_c:.2f})")
    return Analysis({m: r.to_json() for m, r in results.items()}, html, "\n".join(lines))


@procedure(
    "seed000.integral_precession",
    "Integral precession calibration on the vibration table (seed 000)",
    POSITION_PARAMS,
    analyse=analyse_integral,
)
def integral_precession(p: dict):
    plan = multiposition_plan(p["positions_deg"], p["freqs_hz"], p["window_s"])
    yield Note(f"{len(plan)} points at {len(p['positions_deg'])} positions, {p['freqs_hz']} Hz")
    for i, spec in enumerate(plan):
        yield MeasurePoint(point_id(i, spec), spec.position_deg, spec.freq_hz, spec.preset_pulses, p["settle_s"],
                           p["raw"])  # fmt: skip
        if spec.freq_hz == 0:
            yield Checkpoint(f"position {spec.position_deg:g} deg done")
