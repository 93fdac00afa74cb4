"""A simulated station under a controller: real drivers against their emulators, on a VirtualClock (or, with
deterministic=True, on the discrete-event clock and the synchronous transports)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from drivers.config import load_station_config
from drivers.station import SimulatedStation, simulated_station
from station.cli.controller import StationController
from station.store import SessionStore
from station.twin.config import TwinConfig, default_twin

CONFIG = load_station_config(Path(__file__).parents[2] / "config" / "stations/vibration-sim.toml")
# Five positions at 10 Hz with 30 s windows: every coefficient identifiable, about 0.2 h of
# station time, a few seconds of wall time at 1000x.
QUICK = {"positions_deg": [0, 72, 144, 216, 288], "freqs_hz": [10], "window_s": 30, "settle_s": 2}
PROCEDURE = "integral_precession"


@dataclass
class Rig:
    sim: SimulatedStation
    store: SessionStore
    controller: StationController
    messages: list[tuple[str, dict]] = field(default_factory=list)


@pytest.fixture
def make_rig(tmp_path) -> Iterator[Callable[..., Rig]]:
    rigs: list[Rig] = []

    def make(
        twin: TwinConfig | None = None,
        speed: float | None = 1000.0,
        seed: int = 1,
        db: Path | None = None,
        deterministic: bool = True,
    ) -> Rig:
        sim = simulated_station(CONFIG, twin or default_twin(), seed=seed, speed=speed, deterministic=deterministic)
        store = SessionStore(db or tmp_path / "station.sqlite")
        messages: list[tuple[str, dict]] = []
        controller = StationController(
            sim.devices, store, CONFIG.station_model(), reports_dir=tmp_path,
            publish=lambda topic, msg: messages.append((topic, msg)),
        )  # fmt: skip
        rig = Rig(sim, store, controller, messages)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        if rig.controller.busy:
            rig.controller.abort()
            rig.controller.wait(30)
        rig.sim.close()
        rig.store.close()
