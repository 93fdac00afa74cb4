"""The dry run checks a design before anything moves (issue 31): each case of the issue on the console, with the
reason and the fix; refusals exit 2 before the station opens, warnings need --yes."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from station.cli import cli
from station.cli.cli import main
from station.engine.design_checks import bounds_order, equal_modulo_360, long_plan, radians_looking
from station.engine.params import Param
from station.twin.plan import equal_angle_positions_deg

CONFIG = Path(__file__).parents[2] / "config"
ANGLES = (Param("positions_deg", list, unit="deg"),)
RADIANS = [round(math.radians(d), 3) for d in equal_angle_positions_deg(10)]


def _file(tmp_path: Path, procedure: str, **params) -> Path:
    lines = [f"{k} = {v!r}" for k, v in params.items()]
    path = tmp_path / "design.toml"
    path.write_text(f'procedure = "{procedure}"\n[params]\n' + "\n".join(lines) + "\n")
    return path


@pytest.fixture
def station_never_opens(monkeypatch) -> None:
    def refuse(*_a, **_k):
        raise AssertionError("the station was opened")

    monkeypatch.setattr(cli, "open_station", refuse)


def _run(tmp_path: Path, capsys, procedure: str, *options: str, **params) -> tuple[int, str]:
    code = main(["run", str(_file(tmp_path, procedure, **params)), "--out", str(tmp_path / "out"), *options])
    out = capsys.readouterr()
    return code, out.out + out.err


REFUSED = [
    ("integral_precession", {"positions_deg": [-360, 360, 0]},
     ["refused: positions_deg = [-360, 360, 0]: -360, 360, 0 deg are one orientation", "no point excites ky",
      "fix: positions spread over the circle"]),
    ("integral_precession", {"positions_deg": [0, 0, 0, 0, 0]},
     ["refused: positions_deg = [0, 0, 0, 0, 0]", "the design is singular for kz, kzz, ky, k3: no point excites ky"]),
    ("integral_precession.planning", {"n_min": 10, "n_max": 5},
     ["refused: n_min = 10: bounds in the wrong order: n_min = 10 > n_max = 5",
      "fix: n_min <= n_max, e.g. n_min = 5 and n_max = 10"]),
]  # fmt: skip


@pytest.mark.parametrize(("procedure", "params", "words"), REFUSED)
@pytest.mark.parametrize("options", [(), ("--yes",), ("--dry-run",)])
def test_a_design_that_cannot_work_is_refused_before_the_station_opens(
    tmp_path, capsys, station_never_opens, procedure, params, words, options
):
    code, text = _run(tmp_path, capsys, procedure, *options, **params)
    assert code == 2
    assert "the design is refused before anything moves" in text
    assert all(w in text for w in words), text
    assert not (tmp_path / "out" / "station.sqlite").exists()  # no session: nothing opened, nothing moved


WARNED = [
    ({"positions_deg": RADIANS},
     ["warning: positions_deg = [0, 0.628, 1.257", "these look like radians", "fix: give degrees, e.g. [0, 35.98"]),
    ({"positions_deg": [0, 90, 180, 270]},
     ["warning: plan_h = ", "16 measurements take", "over 24 h", "the costliest 5 take 62%", "-90deg-", "-270deg-"]),
    ({"positions_deg": equal_angle_positions_deg(1000)},
     ["warning: plan_h = ", "4000 measurements take", "over 24 h", " and 1650 more; fix"]),
]  # fmt: skip


@pytest.mark.parametrize(("params", "words"), WARNED)
def test_a_doubtful_design_warns_and_runs_only_with_yes(tmp_path, capsys, station_never_opens, params, words):
    code, text = _run(tmp_path, capsys, "integral_precession", "--dry-run", **params)
    assert code == 0 and "dry run of integral_precession" in text
    assert all(w in text for w in words), text
    code, text = _run(tmp_path, capsys, "integral_precession", **params)
    assert code == 2 and "nothing moved; pass --yes to run it anyway" in text
    assert all(w in text for w in words), text
    assert not (tmp_path / "out" / "station.sqlite").exists()
    with pytest.raises(AssertionError, match="the station was opened"):  # --yes goes on to open the station
        _run(tmp_path, capsys, "integral_precession", "--yes", **params)


def test_seed000s_shipped_design_passes_with_no_warning(capsys):
    assert main(["run", str(CONFIG / "procedures" / "integral_precession.toml"), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "40 measurements" in text and "warning" not in text and "refused" not in text


def test_bounds_order_pairs_every_min_with_its_max():
    declared = (Param("n_min", int), Param("n_max", int), Param("freq_min_hz", float), Param("freq_max_hz", float))
    found = bounds_order(declared, {"n_min": 4, "n_max": 4, "freq_min_hz": 10.0, "freq_max_hz": 1.0})
    assert [(f.refusal, f.field, f.value) for f in found] == [(True, "freq_min_hz", 10.0)]


@pytest.mark.parametrize(
    ("values", "radians"),
    [([0.0, 1.5, 3.1], True), ([0.0, 0.0, 0.0], False), ([0.0, 6.0], False), ([0.0, 45.0, 180.0], False),
     ([-6.2, 6.2, 0.0], True), ([0.0, 7.0, 3.0], False)],
)  # fmt: skip
def test_radians_look_like_small_angles_in_degrees(values, radians):
    assert bool(radians_looking(ANGLES, {"positions_deg": values})) is radians


def test_equal_modulo_360_groups_one_orientation():
    (found,) = equal_modulo_360(ANGLES, {"positions_deg": [10.0, 370.0, 90.0, -270.0, 180.0]})
    assert not found.refusal and found.reason.startswith("10, 370; 90, -270 deg are one orientation")
    assert equal_modulo_360(ANGLES, {"positions_deg": [0.0, 359.9, 180.0]}) == []


def test_long_plan_names_the_costliest_points():
    assert long_plan({"a": 3600.0, "b": 7200.0}) == []
    (found,) = long_plan({"cheap": 600.0, "dear": 30 * 3600.0, "dearer": 40 * 3600.0})
    assert not found.refusal and found.field == "plan_h" and found.value == 70.2
    assert "the costliest 1 take 57% of it: dearer 40.0 h"
    (found,) = long_plan({f"P{i}": 3600.0 for i in range(30)})
    assert "the costliest 15 take 50% of it: P0 1.0 h, " in found.reason and "and 7 more" in found.reason
