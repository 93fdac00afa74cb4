"""A lateral resonance's frequency and Q are fitted (profiled), not taken from the twin (issue 10, point 2).

The twin's session has a resonance at 8.5 Hz, Q 6, L0 2 % and kx 2e-4 rad/s/g^2; the default twin's
own resonance parameters are 30 Hz and Q 10, far off. Only kx L0^2 is seen (gap.candidates), and near
resonance the signature's size goes as kx L0^2 Q^2, so that product is what the data fix: allowed 30 %
(Q on a grid of 15 % steps, kx's own uncertainty about 1 %). fr is fixed by the shape at 8, 9 and 10 Hz
to the fine grid's 0.7 % steps: allowed 5 %.
"""

from __future__ import annotations

from gap.api import diagnose
from models.plan import multiposition_plan
from models.session_sim import simulate_session

FR_HZ, Q, L0, KX = 8.5, 6.0, 0.02, 2e-4
PLAN = multiposition_plan([0.0, 60.0, 120.0, 180.0, 240.0, 300.0], (3.0, 5.0, 7.0, 8.0, 9.0, 10.0), window_s=200.0)


def test_a_lateral_resonance_is_explained_with_its_frequency_and_q_fitted(twin):
    cfg = twin.with_effect("lateral_resonance", L0=L0, fr=FR_HZ, Q=Q, phiL=0.0, kx=KX)
    rep = diagnose(simulate_session(PLAN, cfg, 11), twin, suggest=False)
    assert rep.verdict.verdict == "explained" and rep.effects == ["lateral_resonance"], rep.verdict.text
    entry = next(c for c in rep.to_json()["candidates"] if c["name"] == "lateral_resonance")
    fr, q = entry["profiled_parameters"]["fr"], entry["profiled_parameters"]["Q"]
    assert abs(fr / FR_HZ - 1.0) < 0.05
    l0_fit = twin.param("lateral_resonance", "L0") or 0.01  # the candidate's fixed L0 (gap.candidates)
    seen, truth = entry["parameters"]["kx"] * l0_fit**2 * q**2, KX * L0**2 * Q**2
    assert abs(seen / truth - 1.0) < 0.3
    assert rep.twin_out.param("lateral_resonance", "fr") == fr  # the twin out carries the fitted resonance
