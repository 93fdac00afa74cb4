"""What the engine needs of a station: the device protocols it owns and their value types.

The engine drives a station only through these. `drivers.station.StationDevices`
implements `StationHardware` for a real station and, with the same driver code,
for the simulated one; each device driver implements the small protocols that
fit it (`Stoppable` for anything that moves, `Checkable` for a device with a
health check), and the station's stops reach a device by its protocol, never by
guessing at its methods. The value types are what the drivers hand the engine.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from station.clock import Clock
from station.session import StationInfo

# ---------------------------------------------------------------- value types


@dataclass
class WindowResult:
    """One timing window. Times in seconds on the board's (or station's) time base."""

    preset: int
    open_s: float = float("nan")
    close_s: float = float("nan")
    pulses: int = 0
    crossings_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    edges_t_s: np.ndarray | None = None
    edges_dir: np.ndarray | None = None
    edges_lost: int = 0

    @property
    def Tm_s(self) -> float:
        return self.close_s - self.open_s

    @property
    def t1_s(self) -> float | None:
        """First reference crossing after the opening, from the opening."""
        return float(self.crossings_s[0] - self.open_s) if self.crossings_s.size else None

    @property
    def Np(self) -> int | None:
        """Whole periods from t1 to the first crossing at or after the closing."""
        if self.crossings_s.size and self.crossings_s[-1] >= self.close_s:
            return int(self.crossings_s.size - 1)
        return None

    @property
    def t2_s(self) -> float | None:
        """Closing crossing minus the closing time, in [0, T)."""
        if self.Np is None:
            return None
        return float(self.crossings_s[-1] - self.close_s)


@dataclass(frozen=True, slots=True)
class Event:
    """A board event as it arrives: kind is open/ref/edges/close/done/heartbeat."""

    kind: str
    t_s: float
    value: int = 0


@dataclass(frozen=True)
class FrequencyEstimate:
    f_hz: float  # fbar, mean of the per-period frequencies
    sigma_rel: float  # sigma_f / f, seed 000 section 6.1.2
    periods_s: np.ndarray


@dataclass(frozen=True)
class ServoReading:
    """One TPDO sample of the drive's feedback, time-stamped by the station clock."""

    t_s: float
    freq_hz: float
    velocity_radps: float
    position_rad: float  # wraps with the drive's 32-bit position counter


@dataclass(frozen=True)
class MotionRecord:
    """The table's motion over a stretch: grating samples and the reference crossings among them."""

    t_s: np.ndarray
    z_m: np.ndarray
    reference_t_s: np.ndarray


# ---------------------------------------------------------------- device protocols


@runtime_checkable
class Stoppable(Protocol):
    """A device that moves something: brought to rest on a safe stop, stopped at once on an emergency stop."""

    def safe_stop(self) -> None: ...

    def emergency_stop(self) -> None: ...


@runtime_checkable
class Checkable(Protocol):
    """A device with a health check that raises its fault (a station.errors.DeviceError) and returns otherwise."""

    def check(self) -> None: ...


@runtime_checkable
class Closable(Protocol):
    """An opened device or emulator that releases its port or bus on close()."""

    def close(self) -> None: ...


class StationHardware(Protocol):
    """The station as the engine drives it: index, vibrate, time a window, capture, stop."""

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
