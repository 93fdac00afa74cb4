"""The station's devices, opened from its configuration: the one object the engine drives.

`StationDevices.open(config, clock)` opens every driver on the ports and bus
that the configuration names. `simulated_station(config, twin, ...)` first
starts a simulated world (drivers.world.SimStation) on a discrete-event clock,
its emulators on `sim://` serial lines and the `station_sim` CAN interface (or,
for the wire tests, on a VirtualClock behind pseudo-terminals and python-can's
virtual bus), fills their ports into the configuration, then calls the same
`open`: hardware and simulation share every line of driver code.

Interlocks kept here, whatever the procedure asks: the indexing head never
moves while the crank turns (`motion_permitted`), a drive fault or lost bus
raised during a window ends it, and the stops are best effort in order
(counter, crank, head, then every further device with a `safe_stop` or
`emergency_stop` of its own, such as a shaker) so that one failed device does
not keep the others moving.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers import sim_can
from drivers.config import SERIAL_SECTIONS, TABLE_SECTIONS, StationConfig
from drivers.counter_timer.driver import CounterTimer
from drivers.errors import DeviceFault, DeviceTimeout, Disconnected, DriverError, InterlockError, LostSamples
from drivers.grating.driver import GratingReadHead
from drivers.indexing_head.driver import IndexingHead
from drivers.pty_link import Fault
from drivers.reference_marks.driver import ReferenceMarks
from drivers.registry import device_kinds
from drivers.servo.driver import ServoLimits, VibrationTableServo
from station.clock import Clock, VirtualClock, WallClock
from station.engine.protocols import Event, FrequencyEstimate, MotionRecord, ServoReading, Stoppable, WindowResult
from station.event_clock import EventClock, Pacemaker
from station.session import StationInfo
from station.twin.config import TwinConfig

log = logging.getLogger(__name__)

GRATING_RATE_HZ = 5000.0
GRATING_ATTEMPTS = 3  # a host stall of a few hundred ms overflows the board's FIFO: record the stretch again
# The display trace: at most this many grating samples per wall second over the line, so that a
# fast virtual clock gets a thinned (equivalent-time) sample of the motion instead of a backlog.
TRACE_SAMPLES_PER_WALL_S = 250.0
TRACE_DRAIN_WALL_S = 0.05  # the window's events come far more often than this
# A drain waits this long for bytes: a window at 1000x may last 36 ms of wall time, and its only drain, at
# the OPEN event, comes just after the stream starts (what the serial link's 20 ms poll used to grant).
TRACE_WAIT_WALL_S = 0.02


@dataclass
class StationDevices:
    """Open drivers of one station and the operations the engine needs of them."""

    config: StationConfig
    clock: Clock
    servo: VibrationTableServo | None  # the vibration table's devices: all four, or None on a station without one
    grating: GratingReadHead | None
    reference: ReferenceMarks | None
    counter: CounterTimer | None
    head: IndexingHead
    extra: dict[str, Any] = field(default_factory=dict)  # further devices (drivers.registry), by name
    operator: Any = None  # who performs OperatorAction steps; None: a person, through the panel or console
    seed: int | None = None  # a simulated station's random seed (recorded in every session's provenance)
    inject_fault: Callable[[str, str], None] | None = None  # a simulated station's test hook (SimulatedStation.inject)
    _closers: list[Callable[[], None]] = field(default_factory=list, repr=False)
    _freq_hz: float = 0.0

    @property
    def station(self) -> StationInfo:
        s = self.config.station
        return StationInfo(s.A0_m, s.latitude_deg, s.g_mps2, s.earth_rate_radps, s.pulses_per_rev)

    # ---- life cycle -------------------------------------------------------------------

    @classmethod
    def open(cls, config: StationConfig, clock: Clock | None = None) -> StationDevices:
        """Open every device of `config` (ports must be filled in); DriverError names the one that failed."""
        clock = clock or WallClock()
        missing = [n for n in SERIAL_SECTIONS if getattr(config, n) is not None and getattr(config, n).port is None]
        if missing:
            raise InterlockError("station", f"no serial port configured for {', '.join(missing)}")
        opened: list[Callable[[], None]] = []
        kinds = device_kinds()
        devices: StationDevices | None = None
        wiring: dict[str, dict[str, Any]] = {  # what only the station knows, by core device
            "servo": {"limits": ServoLimits.from_config(config)},
            "indexing_head": {"motion_permitted": lambda: devices is not None and devices.table_at_rest()},
        }
        core: dict[str, Any] = dict.fromkeys(TABLE_SECTIONS)
        try:
            for name in config.core_devices():
                core[name] = kinds[name].open(getattr(config, name), clock, **wiring.get(name, {}))
                opened.append(core[name].close)
            servo, grating, reference, counter = (core[name] for name in TABLE_SECTIONS)
            head = core["indexing_head"]
            extra = {}
            for name, section in config.extras.items():
                extra[name] = kinds[name].open(section, clock)
                opened.append(extra[name].close)
        except BaseException:
            for close in reversed(opened):
                with contextlib.suppress(Exception):
                    close()
            raise
        devices = cls(config, clock, servo, grating, reference, counter, head, extra=extra, _closers=opened[::-1])
        return devices

    def close(self) -> None:
        """Bring the table to rest and close every device (best effort, each one)."""
        with contextlib.suppress(DriverError):
            self.safe_stop()
        for close in self._closers:
            try:
                close()
            except Exception as exc:  # closing must reach every device
                log.warning("station close: %s", exc)
        self._closers.clear()

    def __enter__(self) -> StationDevices:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- operations -------------------------------------------------------------------

    def device(self, name: str) -> Any:
        """A further device of this station by name (InterlockError if the station has none)."""
        if name not in self.extra:
            have = ", ".join(self.extra) or "none"
            raise InterlockError("station", f"no device {name!r} in {self.config.path} (further devices: {have})")
        return self.extra[name]

    def table(self) -> tuple[VibrationTableServo, GratingReadHead, ReferenceMarks, CounterTimer]:
        """The vibration table's drive, grating, reference marks and counter; InterlockError on a station
        without a table (its planning refuses such steps first: station.engine.context)."""
        if self.servo is None or self.grating is None or self.reference is None or self.counter is None:
            sections = ", ".join(f"[{name}]" for name in TABLE_SECTIONS)
            raise InterlockError("station", f"{self.config.path} has no vibration table (no {sections})")
        return self.servo, self.grating, self.reference, self.counter

    def table_at_rest(self) -> bool:
        """The crank is not powered, or the drive reads zero speed (the head's motion interlock); always, on a
        station without a table.

        A drive whose state is unknown (no link) or in a quick stop is not at rest until it reads zero."""
        if self.servo is None or self.servo.state not in ("OPERATION ENABLED", "QUICK STOP ACTIVE", "UNKNOWN"):
            return True
        try:
            return self.servo.read().freq_hz == 0.0
        except DriverError:
            return False

    def move_index(self, position_deg: float) -> float:
        """Move the indexing head (the table must be at rest); the settled encoder angle in deg."""
        return self.head.move_to(position_deg)

    def index_position_deg(self) -> float:
        return self.head.position_deg()

    def set_vibration(self, freq_hz: float) -> ServoReading:
        """Ramp the crank to freq_hz (0: to rest, then disable); the drive's reading at speed."""
        servo = self.table()[0]
        if freq_hz == 0.0:
            if servo.state == "OPERATION ENABLED":
                reading = servo.stop()
                servo.disable()
            else:
                reading = servo.read()
            self._freq_hz = 0.0
            return reading
        servo.enable()
        self._freq_hz = freq_hz
        at_speed = servo.set_frequency(freq_hz)
        assert at_speed is not None  # set_frequency waits
        return at_speed

    def measure_window(
        self,
        preset_pulses: int,
        *,
        stream_edges: bool = False,
        on_event: Callable[[Event], None] | None = None,
        grating_s: float = 0.0,
        on_trace: Callable[[np.ndarray, np.ndarray], None] | None = None,
    ) -> tuple[WindowResult, tuple[np.ndarray, np.ndarray]]:
        """One counter window; with grating_s, also that much of the grating record from its start.

        The drive is supervised on every board event: a latched drive fault or bus
        loss ends the window (the board is aborted) with that error. With on_trace,
        the grating streams a thinned display trace for the rest of the window,
        handed over on each board event.
        """
        servo, grating_head, _, counter = self.table()
        trace = None
        try:
            counter.arm(preset_pulses, stream_edges=stream_edges)  # in the try: a lost reply may leave it armed
            grating = self.capture_grating(grating_s) if grating_s > 0 else (np.empty(0), np.empty(0))
            if on_trace is not None:
                trace = _DisplayTrace(grating_head, self.clock, on_trace)

            def supervised(ev: Event) -> None:
                servo.check()
                if trace is not None:
                    trace.drain()
                if on_event is not None:
                    on_event(ev)

            result = counter.wait_window(on_event=supervised)
        except BaseException:
            with contextlib.suppress(DriverError):
                counter.abort()
            raise
        finally:
            if trace is not None:
                trace.stop()
        return result, grating

    def abort_window(self) -> None:
        if self.counter is not None:
            self.counter.abort()

    def capture_grating(self, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
        """duration_s of the 5 kHz grating record: (t_s, z_m) with no sample lost."""
        return self._grating_stretch(duration_s)

    def capture_motion(self, duration_s: float) -> MotionRecord:
        """A grating stretch and the reference crossings (psi = 0) that fall in it, on one time base.

        The crossings fix the crank phase of every sample, so that the harmonics of z(t)
        come out relative to psi as physics.md defines them (seed 000 eq. 30).
        """
        reference = self.table()[2]
        reference.start()
        try:
            t_s, z_m = self._grating_stretch(duration_s)
            crossings: list[float] = []
            while not crossings or crossings[-1] <= t_s[-1]:
                crossings.append(reference.next_crossing().t_s)
        finally:
            with contextlib.suppress(DriverError):
                reference.stop()
        ref = np.asarray(crossings)
        return MotionRecord(t_s, z_m, ref[(ref >= t_s[0]) & (ref <= t_s[-1])])

    def _grating_stretch(self, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
        """A gapless stretch; a stretch with lost samples is recorded again (a read: safe to repeat)."""
        grating = self.table()[1]
        n = max(math.ceil(duration_s * GRATING_RATE_HZ), 1)
        for _ in range(GRATING_ATTEMPTS):
            grating.start_streaming()
            try:
                block = grating.read_for(n)
            finally:
                with contextlib.suppress(DriverError):
                    grating.stop_streaming()
            if not block.lost:
                return block.t_s, block.z_m
            log.warning("grating: %d samples lost in a %g s stretch; recording it again", block.lost, duration_s)
        raise LostSamples(
            "grating read head",
            f"{block.lost} samples lost in a {duration_s:g} s stretch, {GRATING_ATTEMPTS} times",
            field="lost_samples", value=block.lost, allowed="0",
        )  # fmt: skip

    def measure_frequency(self, periods: int) -> FrequencyEstimate:
        """Frequency and stability from `periods` consecutive reference-mark periods (seed 000 6.1.2)."""
        reference = self.table()[2]
        reference.start()
        try:
            return reference.measure_frequency(periods)
        finally:
            with contextlib.suppress(DriverError):
                reference.stop()

    def safe_stop(self) -> None:
        """Abort any window, ramp the crank to rest and disable it; the first error is raised after all."""
        errors: list[DriverError] = []
        table = (self.abort_window, lambda: self.set_vibration(0.0)) if self.servo is not None else ()
        for action in (*table, *self._extra_actions("safe_stop")):
            try:
                action()
            except DriverError as exc:
                errors.append(exc)
        if errors:
            raise errors[0]

    def emergency_stop(self) -> None:
        """Quick stop of the crank, head stopped and held: each tried whatever the others do (any thread)."""
        # Motion only: the counter's port belongs to the thread that reads its window, which aborts it.
        drive = (self.servo.quick_stop,) if self.servo is not None else ()
        actions = (*drive, self.head.hold, *self._extra_actions("emergency_stop"))
        for action in actions:
            try:
                action()
            except DriverError as exc:
                log.error("emergency stop: %s", exc)
        self._freq_hz = 0.0

    def reset(self) -> None:
        """After an emergency stop or a fault, once its cause is removed: the drive's link reopened if it was
        lost, its fault reset (confirmed by the statusword), the head released. The table stays at rest."""
        if self.servo is not None:
            self._reset_drive(self.servo)
        self.head.release()
        self._freq_hz = 0.0

    @staticmethod
    def _reset_drive(servo: VibrationTableServo) -> None:
        try:
            servo.check()
        except (Disconnected, DeviceTimeout):  # a lost bus or heartbeat: only a new connection clears it
            servo.close()
            servo.open()
        except DeviceFault:
            servo.reset_fault()
        if servo.state == "FAULT":
            servo.reset_fault()

    def status(self) -> dict:
        """What the panel shows of the devices, from what the drivers already hold (no I/O); no drive state on a
        station without a table."""
        if self.servo is None:
            return {"drive_state": None, "drive_fault": None, "head_held": self.head.held}
        try:
            self.servo.check()
            fault = None
        except DriverError as exc:
            fault = str(exc)
        return {"drive_state": self.servo.state, "drive_fault": fault, "head_held": self.head.held}

    def tie_heartbeat(self, alive: Callable[[], bool]) -> None:
        """The drive hears the master heartbeat only while alive() holds (station.engine.supervisor)."""
        if self.servo is not None:
            self.servo.master_alive = alive

    def safe_stop_bound_s(self) -> float:
        """Seconds of the clock's link a safe stop may take: the crank's ramp from the highest frequency (station
        time) plus the drive's confirmations (3 SDO writes, 2 state transitions) and the counter abort; on a
        station without a table, the further devices' stops (a second each, as the table's confirmations)."""
        if self.config.servo is None:
            return 1.0 + 1.0 * len(self._extra_actions("safe_stop"))
        lim = self.config.limits
        return (
            self.clock.link_s(lim.freq_max_hz / lim.ramp_max_hz_per_s) + 3 * self.config.servo.timeout_s + 2 * 1.0 + 1.0
        )

    def _extra_actions(self, name: str) -> list[Callable[[], object]]:
        """The safe_stop / emergency_stop of every further device that moves something
        (station.engine.protocols.Stoppable)."""
        return [getattr(d, name) for d in self.extra.values() if isinstance(d, Stoppable)]


def display_divider(pace: float | None, max_divider: int) -> int:
    """The grating's divider for the display trace: about TRACE_SAMPLES_PER_WALL_S samples per wall second at
    `pace` (None: as fast as the CPU allows, the largest divider), up to a quarter more, prime to 10 (so that
    5 kHz / divider is a submultiple of no table frequency on the 0.1 Hz grid) and among those the one whose samples
    walk fastest through the phase of every whole-hertz motion, 1 to 10 Hz: an equivalent-time sample of the motion
    rather than a strobe (2000 at 100x is 2.5 Hz, and every sample of a 10 Hz motion read the same z)."""
    target = max_divider if pace is None else math.ceil(GRATING_RATE_HZ * pace / TRACE_SAMPLES_PER_WALL_S)
    hi = min(max(target, 11), max_divider)
    candidates = [d for d in range(max(11, int(0.8 * hi)), hi + 1) if math.gcd(d, 10) == 1]

    def slowest_walk(d: int) -> float:  # cycles of the motion between two samples, from the nearest whole cycle
        return min(abs(f_hz * d / GRATING_RATE_HZ - round(f_hz * d / GRATING_RATE_HZ)) for f_hz in range(1, 11))

    return max(candidates, key=slowest_walk)


class _DisplayTrace:
    """The grating streaming at a display rate during a window; samples handed over as they come.

    Display only: a lost or damaged sample costs a point of the trace, never the window.
    """

    def __init__(self, grating: GratingReadHead, clock: Clock, sink: Callable[[np.ndarray, np.ndarray], None]) -> None:
        divider = display_divider(clock.pace, grating.max_divider)
        self.grating = grating
        self.sink = sink
        self._link = clock.link  # the drain's pace is the line's
        self.errors = 0
        self._last_drain = -math.inf
        grating.start_streaming(divider)

    def drain(self) -> None:
        now = self._link.now_s()
        if now - self._last_drain < TRACE_DRAIN_WALL_S:
            return
        self._last_drain = now
        try:
            block = self.grating.read_block(max_samples=5000, timeout_s=TRACE_WAIT_WALL_S)
        except DeviceTimeout:
            return  # nothing new yet
        except DriverError:
            self.errors += 1
            return
        if len(block):
            self.sink(block.t_s, block.z_m)

    def stop(self) -> None:
        with contextlib.suppress(DriverError):
            self.grating.stop_streaming()


@dataclass
class SimulatedStation:
    """A simulated world with its emulators running; `devices` are the real drivers opened on them."""

    world: Any
    emulators: dict[str, Any]
    devices: StationDevices
    can_channel: str = ""
    pacemaker: Pacemaker | None = None  # a paced station's time flows on whoever waits (station.event_clock)

    def inject(self, device: str, fault: str) -> None:
        """Arm one occurrence of `fault` (a Fault value: crc_error, garble, ...) in the emulator of `device`, for
        tests from outside the process (the control channel's `inject`); ValueError names what it cannot take."""
        emulator = self.emulators.get(device)
        if emulator is None or not hasattr(emulator, "inject"):
            takers = ", ".join(name for name, emu in self.emulators.items() if hasattr(emu, "inject"))
            raise ValueError(f"device {device!r} takes no injected faults; these do: {takers}")
        emulator.inject(Fault(fault))

    def close(self) -> None:
        self.devices.close()
        _stop_emulators(self.emulators)
        if self.can_channel:
            sim_can.bind_clock(self.can_channel, None)
        if self.pacemaker is not None:
            self.pacemaker.stop()

    def __enter__(self) -> SimulatedStation:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _stop_emulators(emulators: dict[str, Any]) -> None:
    for name, emu in reversed(emulators.items()):
        try:
            emu.stop() if name == "servo" else emu.close()  # the CAN node stops, the others close
        except Exception as exc:  # every emulator must be stopped
            log.warning("stopping the %s emulator: %s", name, exc)


def simulated_station(
    config: StationConfig,
    twin: TwinConfig,
    *,
    seed: int = 0,
    speed: float | None = None,
    deterministic: bool = True,
) -> SimulatedStation:
    """Start the simulated station of `config` (which must say simulated = true) and open its drivers.

    Each station gets its own CAN channel so that several can run in one process. The world runs,
    `deterministic` (the default), on a discrete-event clock (station.event_clock) with the
    synchronous transports (the `station_sim` CAN interface, sim:// serial lines): the same seed then gives
    the same session to the bit, however busy the host (the threads that act in station time are parties
    of the clock: the controller's engine, the supervisor's safe stop, or a lone caller). There `speed`
    caps the pace at that many station seconds per wall second and keeps time flowing, as a real
    station's, whoever acts on it (a Pacemaker), for watching it live; without it the station runs as
    fast as the CPU allows. Not `deterministic` (the wire tests): on a VirtualClock `speed` (default 1)
    times real time, the emulators behind pseudo-terminals and on python-can's virtual bus.
    """
    from drivers.world import SimStation

    if not config.simulated:
        raise InterlockError("station", f"{config.path} is a real station's configuration (simulated = false)")
    clock: Clock = EventClock(ceiling=speed) if deterministic else VirtualClock(speed or 1.0)
    world = SimStation(
        twin, clock, seed=seed, index_speed_deg_s=config.indexing_head.speed_deg_s, sim_lines=deterministic
    )
    channel = ""
    if config.servo is not None:
        channel = f"{config.servo.channel}-{uuid.uuid4().hex[:8]}"
        servo_cfg = dataclasses.replace(config.servo, channel=channel)
        if deterministic:
            servo_cfg = dataclasses.replace(servo_cfg, interface=sim_can.INTERFACE)
            sim_can.bind_clock(channel, clock)
        config = dataclasses.replace(config, servo=servo_cfg)
    emulators: dict[str, Any] = {}
    kinds = device_kinds()
    try:
        for name in config.core_devices():
            emulators[name] = kinds[name].emulate(getattr(config, name), world)
        for name, section in config.extras.items():
            emulators[name] = kinds[name].emulate(section, world)
        ports = {name: emu.port for name, emu in emulators.items() if getattr(emu, "port", None)}
        devices = StationDevices.open(config.with_serial_ports(**ports), clock)
        devices.operator = world.operator
        devices.seed = seed
    except BaseException:
        _stop_emulators(emulators)
        if channel:
            sim_can.bind_clock(channel, None)
        raise
    pacemaker = Pacemaker(clock) if isinstance(clock, EventClock) and clock.ceiling is not None else None
    sim = SimulatedStation(world, emulators, devices, channel, pacemaker)
    devices.inject_fault = sim.inject
    return sim
