"""Validation and dry run: every defect is refused before anything moves, with the field, value and
what is allowed; the time estimates agree with the station."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from drivers.config import load_station_config
from station.engine.context import StationModel, ValidationError
from station.engine.params import Param, ParameterError
from station.engine.planning import plan_procedure
from station.engine.registry import ProcedureError, ProcedureSpec, get_procedure, load_procedure_file
from station.engine.steps import MeasurePoint, MoveIndex, SetVibration

from .conftest import CONFIG

MODEL = CONFIG.station_model()
CONFIG_DIR = Path(__file__).parents[2] / "config"
PROCEDURES = CONFIG_DIR / "procedures"


def _spec(*steps) -> ProcedureSpec:
    def proc(p):
        for s in steps:  # noqa: UP028 - the engine sends results back, which a tuple iterator cannot take
            yield s

    return ProcedureSpec("test.steps", "steps", (), proc)


def test_every_shipped_procedure_file_plans() -> None:
    """On the core station, or (a procedure with further devices) on a simulated station file that has them."""
    stations = sorted(CONFIG_DIR.glob("stations/*-sim.toml"))
    models = [MODEL] + [load_station_config(f).station_model() for f in stations]
    for path in sorted(PROCEDURES.glob("*.toml")):
        spec, params = load_procedure_file(path)
        refusals = []
        for model in models:
            try:
                plan = plan_procedure(spec, params, model)
            except ValidationError as exc:
                refusals.append(str(exc))
                continue
            assert plan.total_s >= 0, path
            break
        else:
            pytest.fail(f"{path} plans on no simulated station: {refusals}")


def test_seed000_dry_run_estimates_the_session() -> None:
    spec, params = load_procedure_file(PROCEDURES / "integral_precession.toml")
    plan = plan_procedure(spec, params, MODEL)
    est = plan.key_estimates_s()
    assert len(est) == 40
    # Each position: three vibration windows and a static one of about 560 s (P chosen for 560 s, whole
    # revolutions: within half a revolution, 2 pi / (2 * 0.56 cos 36) = 6.9 s at the worst of these positions).
    windows = [s.nominal.Tm_s for s in plan.measurements]
    assert all(abs(t - 560) < 0.5 * 2 * math.pi / (0.56 * math.cos(math.radians(72))) for t in windows)
    # 7 h of station time, as seed 000 says (about 6.2 h of windows, ramps and settling).
    assert 6.0 * 3600 < plan.total_s < 7.0 * 3600


@pytest.mark.parametrize(
    ("params", "named"),
    [
        ({"freqs_hz": [12.0]}, "'freqs_hz'[0] = 12.0: out of range, allowed list of numbers in [0.1, 10] Hz"),
        ({"positions_deg": "0, 90"}, "'positions_deg' = '0, 90': expected a non-empty list of numbers"),
        ({"window_s": -5}, "'window_s' = -5: out of range, allowed float in [1, 100000] s"),
        ({"settle_s": True}, "'settle_s' = True: expected float in [0, 600] s"),
        ({"speed": 3}, "unknown parameter(s) 'speed'; allowed: positions_deg, freqs_hz"),
    ],
)
def test_bad_parameters_name_the_field_the_value_and_what_is_allowed(params, named) -> None:
    with pytest.raises(ParameterError) as info:
        get_procedure("integral_precession").validate(params)
    assert named in str(info.value)


def test_malformed_procedure_file_is_refused(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('procedure = "integral_precession"\n[params]\nfreqs_hz = [8, 11]\n')
    with pytest.raises(ProcedureError, match=r"bad.toml.*freqs_hz.*11.*\[0.1, 10\]"):
        load_procedure_file(bad)
    bad.write_text("procedure = [\n")
    with pytest.raises(ProcedureError, match="not valid TOML"):
        load_procedure_file(bad)
    bad.write_text('procedure = "no.such"\n')
    with pytest.raises(ProcedureError, match=r"unknown procedure 'no\.such'.*integral_precession"):
        load_procedure_file(bad)


PAYLOAD_MODEL = StationModel(accel_min_g=0.002)  # a payload that needs at least 0.002 g: 0.1 Hz gives 0.0012 g


@pytest.mark.parametrize(
    ("step", "model", "field", "allowed"),
    [
        (SetVibration(10.5), MODEL, "freq_hz = 10.5", "0 (static) or 0.1 .. 10 Hz"),
        (SetVibration(0.1), PAYLOAD_MODEL, "acceleration amplitude = 0.0012", "0.002 .. 12.5 g"),
        (MoveIndex(800.0), MODEL, "position_deg = 800.0", "-720 .. 720 deg"),
        (MeasurePoint("p1", 0.0, 9.0, 0), MODEL, "preset_pulses = 0", "a whole number 1 .. 2147483647"),
        (MeasurePoint("p1", 0.0, math.nan, 10), MODEL, "freq_hz = nan", "0 (static) or 0.1 .. 10 Hz"),
    ],
)
def test_a_step_beyond_the_limits_fails_the_plan(step, model, field, allowed) -> None:
    with pytest.raises(ValidationError) as info:
        plan_procedure(_spec(MoveIndex(0.0), step), {}, model)
    msg = str(info.value)
    assert msg.startswith(f"step 1 {type(step).__name__}") and field in msg and msg.endswith(allowed)


def test_duplicate_measurement_keys_and_missing_devices_are_refused() -> None:
    with pytest.raises(ValidationError, match=r"key = 'p1'.* used once per session"):
        plan_procedure(_spec(MeasurePoint("p1", 0, 0, 16384), MeasurePoint("p1", 36, 0, 16384)), {}, MODEL)

    class NeedsVoltmeter(SetVibration):
        def plan(self, ctx):
            ctx.require("voltmeter")
            return super().plan(ctx)

    with pytest.raises(ValidationError, match=r"device = 'voltmeter'.* a device of this station"):
        plan_procedure(_spec(NeedsVoltmeter(1.0)), {}, MODEL)


def test_declared_parameters_describe_themselves_for_forms() -> None:
    p = Param("freqs_hz", list, default=[8.0], min=0.1, max=10.0, unit="Hz", help="h")
    d = p.describe()
    assert d["allowed"] == "list of numbers in [0.1, 10] Hz"
    assert d == {"name": "freqs_hz", "label": "freqs (Hz)", "kind": "list", "default": [8.0], "min": 0.1, "max": 10.0,
                 "choices": None, "unit": "Hz", "help": "h", "required": False, "allowed": d["allowed"]}  # fmt: skip
