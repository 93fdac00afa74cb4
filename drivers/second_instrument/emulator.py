"""Two PIGAs on the simulated indexing head (seed 003's dual-instrument fixture) and what the second one's counter sees.

`DualFixture` (one per world, `world.shared`) knows which pose each PIGA sits in; the
simulated operator re-installs them on the action {"fixture_poses": [pose_a, pose_b]}.
PIGA A is the world's twin: its mount angle (pose angle, seat error and its own input-axis
error) goes into the world's `mount_misalignment`. PIGA B has its own coefficients and
mount on the same head; `InstrumentOnHead` is B as a counter sees it: the world's clock,
crank, head and reference crossings, B's twin and its own noise draws. The station's
CounterEmulator, fed by it, is B's counter channel.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from typing import Any

import numpy as np

from drivers.counter_timer.emulator import CounterEmulator
from drivers.errors import DriverError
from drivers.world import CROSSINGS_AHEAD_S, SimStation
from station.twin.config import InstrumentCoefficients, TwinConfig
from station.twin.fixture import POSES_DEG, SETUPS, mounted_twin, pose_rad
from station.twin.inputs import instrument_rate_radps

FIXTURE = "dual_fixture"
# Seat errors of the fixture's four poses (rad): pose 1 is the reference. All within the
# 30 arc-second installation tolerance of seed 003 5.3 (1.45e-4 rad).
SEAT_ERRORS_RAD: Mapping[int, float] = {1: 0.0, 2: 1.5e-5, 3: -1.0e-5, 4: 2.5e-5}
# PIGA B: a second instrument of seed 003's model (no cubic term) with seed 000's coefficients.
INSTRUMENT_B = InstrumentCoefficients(k3=0.0)
IA_ERROR_B_RAD = -1.0e-5


class DualFixture:
    """Which pose each PIGA is in; A starts in pose 1 with the world twin's mount as its own input-axis error."""

    def __init__(
        self,
        world: SimStation,
        seat_errors_rad: Mapping[int, float] = SEAT_ERRORS_RAD,
        instrument_b: InstrumentCoefficients = INSTRUMENT_B,
        ia_error_b_rad: float = IA_ERROR_B_RAD,
    ) -> None:
        self.world = world
        self.seat_errors_rad = dict(seat_errors_rad)
        self.instrument_b = instrument_b
        self.ia_error_rad = {"A": world.twin.param("mount_misalignment", "dtheta_mount"), "B": ia_error_b_rad}
        self.poses = dict(zip(("A", "B"), SETUPS[1], strict=True))
        world.on_operator("fixture_poses", self.reinstall)

    def mount_rad(self, instrument: str) -> float:
        """Pose angle + seat error + the instrument's own input-axis error."""
        pose = self.poses[instrument]
        return pose_rad(pose) + self.seat_errors_rad[pose] + self.ia_error_rad[instrument]

    def twin_b(self) -> TwinConfig:
        """B's twin as installed now: the station's effects, B's coefficients and mount."""
        return mounted_twin(self.world.twin, self.mount_rad("B"), self.instrument_b)

    def reinstall(self, value: Any, t_s: float) -> None:
        """The operator puts A and B in the poses [pose_a, pose_b]."""
        ok = isinstance(value, list | tuple) and len(value) == 2 and all(v in POSES_DEG for v in value)
        if not ok or value[0] == value[1]:
            raise DriverError("simulated operator", "cannot install the PIGAs so", field="fixture_poses", value=value,
                              allowed="two different poses of 1, 2, 3, 4 as [pose of A, pose of B]")  # fmt: skip
        self.poses = {"A": int(value[0]), "B": int(value[1])}
        self.world.set_twin(mounted_twin(self.world.twin, self.mount_rad("A")))


def static_rates_radps(twin: TwinConfig, setup: int, heads_rad: np.ndarray) -> dict[str, tuple[int, np.ndarray]]:
    """Noise-free static rates of PIGAs A (`twin`) and B in a fixture setup at head angles, by instrument:
    (its pose, its rates). The simulated fixture's physics without the station, for design studies."""
    fixture = DualFixture(SimStation(twin))
    fixture.reinstall(list(SETUPS[setup]), 0.0)
    twins = {"A": fixture.world.twin, "B": fixture.twin_b()}
    return {i: (fixture.poses[i], np.array([float(instrument_rate_radps(h, 0.0, 0.0, tw)) for h in heads_rad]))
            for i, tw in twins.items()}  # fmt: skip


class InstrumentOnHead(SimStation):
    """PIGA B on the world's indexing head, as its counter/timer sees it.

    Built without SimStation.__init__, which would make a crank and a head of its own:
    this one shares the world's, re-anchors whenever the world changes (crank, head,
    fixture or physics) and inherits SimStation's window and pulse-edge machinery.
    """

    def __init__(self, world: SimStation, fixture: DualFixture) -> None:
        self.world = world
        self.fixture = fixture
        self.clock = world.clock
        self.crank = world.crank
        self.rng = np.random.default_rng(int(world.rng.integers(2**63)))
        self._lock = threading.RLock()
        self._anchor = None
        self._crossings_ahead_s = CROSSINGS_AHEAD_S
        self._crossings = None
        self._edge_phase_rad = float(self.rng.uniform(0.0, 2 * math.pi / world.twin.station.pulses_per_rev))

    @property
    def twin(self) -> TwinConfig:  # type: ignore[override]  # PIGA B's twin, read-only: the fixture owns it
        return self.fixture.twin_b()

    @property
    def _version(self) -> int:  # type: ignore[override]  # the world's, so PIGA B follows every twin change
        return self.world._version

    def index_position_deg(self, t_s: float) -> float:
        return self.world.index_position_deg(t_s)


def start_counter_emulator(world: SimStation, baud: int) -> CounterEmulator:
    """PIGA B on the world's fixture (made on first use) behind a counter/timer emulator of its own."""
    fixture = world.shared(FIXTURE, lambda: DualFixture(world))
    emulator = CounterEmulator(InstrumentOnHead(world, fixture), baud=baud)
    emulator.name = "second-counter-emulator"
    return world.attach(emulator)
