"""What the engine needs of a station: the seam between the engine and the drivers.

`devices.station.StationDevices` implements it, for a real station and, with
the same driver code, for the simulated one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from devices.counter_timer.driver import Event, WindowResult
from devices.reference_marks.driver import FrequencyEstimate
from devices.servo.driver import ServoReading
from devices.station import MotionRecord
from station.clock import Clock
from station.session import StationInfo


class StationHardware(Protocol):
    clock: Clock

    @property
    def station(self) -> StationInfo: ...

    def move_index(self, position_deg: float) -> float: ...

    def set_vibration(self, freq_hz: float) -> ServoReading: ...

    def measure_window(
        self,
        preset_pulses: int,
        *,
        stream_edges: bool = False,
        on_event: Callable[[Event], None] | None = None,
        grating_s: float = 0.0,
        on_trace: Callable[[np.ndarray, np.ndarray], None] | None = None,
    ) -> tuple[WindowResult, tuple[np.ndarray, np.ndarray]]: ...

    def capture_grating(self, duration_s: float) -> tuple[np.ndarray, np.ndarray]: ...

    def capture_motion(self, duration_s: float) -> MotionRecord: ...

    def measure_frequency(self, periods: int) -> FrequencyEstimate: ...

    def device(self, name: str) -> Any: ...

    def safe_stop(self) -> None: ...

    def emergency_stop(self) -> None: ...

    def reset(self) -> None: ...

    def status(self) -> dict: ...
