"""Vibration-table crank servo: a CiA 402 drive in profile velocity mode over CANopen.

The table vibrates at the crank's rotation frequency f = w / 2 pi. Drive units
(config/eds/vibration_table_servo.eds): velocity 1e-6 rev/s, so target velocity
0x60FF = f / 1e-6 (the frequency in uHz); ramps 0x6083/0x6084/0x6085 in
1e-6 rev/s^2 (uHz/s); position 0x6064 in 1/65536 rev. Statusword, mode display,
velocity and position come by TPDO; controlword and mode go by RPDO; parameters
and targets by confirmed SDO.

Safety rules:
- limits (frequency, acceleration amplitude A0 (2 pi f)^2 / g, ramp) are checked
  before anything is sent: LimitError, and nothing moves;
- motion commands are never retried (an SDO timeout on a write leaves the drive's
  state unknown and raises DeviceTimeout); SDO reads are retried once;
- every wait is bounded and raises DeviceTimeout, DeviceFault or BusOff;
- the driver produces a heartbeat (node MASTER_NODE_ID) that the drive consumes
  (0x1016), only while `master_alive()` holds (the station's supervisor of motion
  sets it: a master whose supervision is lost must fall silent, or the drive's
  watchdog never fires), and configures what the drive does on its own when that
  heartbeat stops: 0x6007 abort connection option = 1 (fault signal: the drive
  faults with EMCY 0x8130 and brakes on the quick-stop ramp) and 0x605A quick stop
  option = 2 (quick-stop ramp 0x6085, then SWITCH ON DISABLED, which quick_stop()
  waits for); both written and read back at open (DeviceFault if the drive does
  not keep them);
- the driver consumes the drive's heartbeat (0x1017): a drive silent for HEARTBEAT_FACTOR
  heartbeat periods latches DeviceTimeout (TPDOs still arriving) or BusOff (node
  silent altogether) and gets a best-effort quick stop; EMCY latches DeviceFault.
  Latched errors are raised by the next call (or by check()/watch()).
Protocol waits are in real time; reading time stamps come from the station clock.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, cast

import can
import canopen
from canopen.emcy import EmcyError
from canopen.pdo import PdoMap
from canopen.profiles.p402 import BaseNode402
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.config import ServoSection, StationConfig
from drivers.errors import (
    BusOff,
    DeviceFault,
    DeviceTimeout,
    Disconnected,
    DriverError,
    InterlockError,
    LimitError,
)
from drivers.servo.protocol import (
    ACCEL_UNIT_HZ_PER_S,
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_QUICK_STOP,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    MODE_PROFILE_VELOCITY,
    POSITION_UNITS_PER_REV,
    RPDO_OBJECTS,
    SUPPORTED_MODE_PV_BIT,
    SW_FAULT,
    SW_TARGET_REACHED,
    TPDO_OBJECTS,
    VELOCITY_UNIT_HZ,
    state_of,
)
from station.clock import Clock, TimerHandle, WallClock
from station.engine.protocols import ServoReading

log = logging.getLogger(__name__)

TWO_PI = 2.0 * math.pi

MASTER_NODE_ID = 0x7F
ABORT_CONNECTION_OPTION = 1  # 0x6007: fault signal on a lost master (CiA 402)
QUICK_STOP_OPTION = 2  # 0x605A: quick-stop ramp, then SWITCH ON DISABLED
NOTIFIER_CYCLE_S = 0.05  # bounds how long close() waits for the receive thread
HEARTBEAT_FACTOR = 3  # consumer time = 3 producer periods, on both sides
READ_ATTEMPTS = 2
STATE_TIMEOUT_S = 1.0  # one 402 state transition
FAULT_RESET_TIMEOUT_S = 1.0
AT_SPEED_TOL_HZ = 1e-3  # velocity window for "at speed", like 0x606D
RAMP_MARGIN_S = 0.5  # added to the ramp time when waiting for a speed
_ENABLE_PATH = (
    (CW_SHUTDOWN, "READY TO SWITCH ON"),
    (CW_SWITCH_ON, "SWITCHED ON"),
    (CW_ENABLE_OPERATION, "OPERATION ENABLED"),
)


def _target_reached(statusword: int) -> bool:
    return bool(statusword & SW_TARGET_REACHED)


def _at_rest_stopped(statusword: int) -> bool:
    """After a quick stop with option QUICK_STOP_OPTION (2): SWITCH ON DISABLED, or FAULT if the drive faulted."""
    return state_of(statusword) in ("SWITCH ON DISABLED", "FAULT")


@dataclass(frozen=True)
class ServoLimits:
    """What the table may be asked to do (from the station config)."""

    freq_min_hz: float
    freq_max_hz: float
    accel_min_g: float
    accel_max_g: float
    ramp_max_hz_per_s: float
    A0_m: float
    g_mps2: float

    @classmethod
    def from_config(cls, cfg: StationConfig) -> ServoLimits:
        lim = cfg.limits
        return cls(
            freq_min_hz=lim.freq_min_hz,
            freq_max_hz=lim.freq_max_hz,
            accel_min_g=lim.accel_min_g,
            accel_max_g=lim.accel_max_g,
            ramp_max_hz_per_s=lim.ramp_max_hz_per_s,
            A0_m=cfg.station.A0_m,
            g_mps2=cfg.station.g_mps2,
        )

    def accel_g(self, freq_hz: float) -> float:
        """Acceleration amplitude A0 (2 pi f)^2 / g of the nominal motion."""
        return self.A0_m * (TWO_PI * freq_hz) ** 2 / self.g_mps2

    def check(self, device: str, freq_hz: float, ramp_hz_per_s: float) -> None:
        """Raise LimitError unless the frequency, its acceleration and the ramp are allowed."""
        if not (math.isfinite(freq_hz) and self.freq_min_hz <= freq_hz <= self.freq_max_hz):
            raise LimitError(
                device,
                "out of range",
                field="freq_hz",
                value=freq_hz,
                allowed=f"{self.freq_min_hz:g} .. {self.freq_max_hz:g} Hz",
            )
        accel_g = self.accel_g(freq_hz)
        if not self.accel_min_g <= accel_g <= self.accel_max_g:
            raise LimitError(
                device,
                f"acceleration amplitude out of range at {freq_hz:g} Hz",
                field="accel_g",
                value=round(accel_g, 6),
                allowed=f"{self.accel_min_g:g} .. {self.accel_max_g:g} g (A0 (2 pi f)^2 / g, A0 = {self.A0_m:g} m)",
            )
        self.check_ramp(device, ramp_hz_per_s)

    def check_ramp(self, device: str, ramp_hz_per_s: float) -> None:
        if not (math.isfinite(ramp_hz_per_s) and 0 < ramp_hz_per_s <= self.ramp_max_hz_per_s):
            raise LimitError(
                device,
                "out of range",
                field="ramp_hz_per_s",
                value=ramp_hz_per_s,
                allowed=f"0 < ramp <= {self.ramp_max_hz_per_s:g} Hz/s",
            )


class Reception(NamedTuple):
    """One TPDO-mapped object as a TPDO brought it, with the rest of that TPDO (`together`): one instant's values."""

    value: int
    seq: int
    t_s: float
    together: dict[int, int]


class _TpdoCache:
    """Last value, reception count and station time of every TPDO-mapped object; receptions are awaited
    on the link clock (station.clock)."""

    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self._link = clock.link
        self._cond = self._link.condition()
        self._values: dict[int, int] = {}
        self._seq: dict[int, int] = {}
        self._t_s: dict[int, float] = {}
        self._together: dict[int, dict[int, int]] = {}
        self.last_rx_link_s = self._link.now_s()

    def on_pdo(self, pdo_map: PdoMap) -> None:
        t_s = self._clock.now_s()
        together = {var.index: int(var.od.decode_raw(var.data)) for var in pdo_map}  # var.raw formats a debug text
        with self._cond:
            self._values.update(together)
            for index in together:
                self._seq[index] = self._seq.get(index, 0) + 1
                self._t_s[index] = t_s
                self._together[index] = together
            self.last_rx_link_s = self._link.now_s()
            self._cond.notify_all()

    def seq(self, index: int) -> int:
        with self._cond:
            return self._seq.get(index, 0)

    def reception(self, index: int, after_seq: int, *, timeout_s: float) -> Reception | None:
        """The first reception numbered after after_seq (the latest one, when several came meanwhile), or None
        after timeout_s."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._seq.get(index, 0) > after_seq, timeout_s=timeout_s):
                return None
            return Reception(self._values[index], self._seq[index], self._t_s[index], self._together[index])

    def latest(self, index: int) -> int:
        with self._cond:
            return self._values[index]


class VibrationTableServo:
    """Driver of the crank servo. Use as a context manager, or open()/close()."""

    DEVICE = "vibration table servo"

    def __init__(self, servo: ServoSection, limits: ServoLimits, clock: Clock | None = None) -> None:
        self._cfg = servo
        self._limits = limits
        self._clock = clock if clock is not None else WallClock()
        self._link = self._clock.link  # times the bus protocol: heartbeats, their watchdog, every reply timeout
        self._tpdo = _TpdoCache(self._clock)
        self._network: canopen.Network | None = None
        self._node: BaseNode402 | None = None
        self._hb_timer: TimerHandle | None = None
        self.master_alive: Callable[[], bool] = lambda: True  # the heartbeat goes out only while this holds
        self._hb_period_s = servo.heartbeat_ms / 1000.0
        self._hb_timeout_s = HEARTBEAT_FACTOR * self._hb_period_s
        self._hb_last_link_s = self._link.now_s()
        self._hb_heard = self._link.event()
        self._watchdog_lock = threading.Lock()
        self._watchdog: TimerHandle | None = None
        self._watching = False
        self._pdo_silence_s = self._hb_timeout_s
        self._qs_decel_hz_per_s = 0.0
        self._cw_lock = threading.Lock()
        self._err_lock = threading.Lock()
        self._link_error: DriverError | None = None
        self._fault: DeviceFault | None = None
        self._error_event = self._link.event()

    # ---- life cycle -------------------------------------------------------------------

    @property
    def node(self) -> BaseNode402:
        """The drive's node while the driver is open (Disconnected otherwise)."""
        if self._node is None:
            raise Disconnected(self.DEVICE, "the drive is not open")
        return self._node

    @property
    def network(self) -> canopen.Network:
        if self._network is None:
            raise Disconnected(self.DEVICE, "the CAN network is not open")
        return self._network

    def open(self) -> None:
        """Connect, set up heartbeats and PDOs, go NMT OPERATIONAL, select and verify PV mode."""
        cfg = self._cfg
        if self._network is not None:
            raise InterlockError(self.DEVICE, "already open")
        self._tpdo = _TpdoCache(self._clock)  # a new session: nothing stale, nothing latched
        self._link_error = self._fault = None
        self._error_event.clear()
        try:
            bus = can.Bus(interface=cfg.interface, channel=cfg.channel)
        except (can.CanError, OSError, ValueError) as e:
            where = f"{cfg.interface}:{cfg.channel}"
            raise Disconnected(self.DEVICE, f"cannot open CAN {where}: {e}") from e
        self._network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        try:
            self.network.connect()
            self._setup()
        except BaseException:
            self._disconnect()
            raise

    def _setup(self) -> None:
        node = BaseNode402(self._cfg.node_id, str(self._cfg.eds))
        self._node = node
        self.network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = self._cfg.timeout_s
        node.sdo.MAX_RETRIES = 1  # one attempt per request; reads retry in _sdo_read
        node.emcy.add_callback(self._on_emcy)
        node.nmt.add_heartbeat_callback(self._on_heartbeat)

        self._sdo_read(0x1000)  # the drive answers
        self._hb_heard.clear()
        self._sdo_write(0x1017, self._cfg.heartbeat_ms)
        if not self._hb_heard.wait(timeout_s=self._hb_timeout_s):
            raise DeviceTimeout(
                self.DEVICE,
                f"no heartbeat within {self._hb_timeout_s:g} s",
                field="0x1017",
                value=self._cfg.heartbeat_ms,
                allowed="a drive producing its heartbeat",
            )
        # our heartbeat (NMT state 0x05, OPERATIONAL), consumed by the drive through 0x1016: a timer of the
        # link clock for as long as the driver is connected, supervised run or not
        self._produce_heartbeat()
        self._hb_timer = self._link.call_every(self._hb_period_s, self._produce_heartbeat)
        self._configure_master_loss()
        consumer_ms = round(HEARTBEAT_FACTOR * self._cfg.heartbeat_ms)
        self._sdo_write(0x1016, (MASTER_NODE_ID << 16) | consumer_ms, subindex=1)

        node.nmt.state = "PRE-OPERATIONAL"
        try:
            node.setup_402_state_machine(read_pdos=True)
        except (SdoCommunicationError, SdoAbortedError) as e:
            raise DeviceTimeout(self.DEVICE, f"reading the PDO configuration failed: {e}") from e
        self._check_pdo_mapping()
        self._set_tpdo_event_timers()
        timers_s = [t.event_timer / 1000 for t in node.tpdo.values() if t.enabled and t.event_timer]
        self._pdo_silence_s = min(self._hb_timeout_s, 5 * max(timers_s, default=self._hb_period_s))
        for tpdo in node.tpdo.values():
            if tpdo.enabled:
                # this cache (on the station clock) is what the driver reads: BaseNode402's own copy
                # (tpdo_values, read by none of its methods that we call) would decode every frame twice
                if node.on_TPDOs_update_callback in tpdo.callbacks:
                    tpdo.callbacks.remove(node.on_TPDOs_update_callback)
                tpdo.add_callback(self._tpdo.on_pdo)
        node.nmt.state = "OPERATIONAL"
        for index in (0x6041, 0x606C):
            self._fresh(index, 0, f"first TPDO with 0x{index:04X}")

        self._select_profile_velocity()
        qs_decel = self._sdo_read(0x6085)
        self._qs_decel_hz_per_s = qs_decel * ACCEL_UNIT_HZ_PER_S
        with self._watchdog_lock:
            self._watching = True
            self._arm_watchdog()

    def close(self) -> None:
        """Bring the crank to rest and disable (best effort), stop heartbeats, leave the bus."""
        if self._network is None:
            return
        self._stop_watchdog()
        if self._link_error is None and self._node is not None:
            try:
                if self.state in ("OPERATION ENABLED", "QUICK STOP ACTIVE"):
                    self.disable()
                self._sdo_write(0x1016, 0, subindex=1)  # a deliberate exit, not a lost master
            except DriverError as e:
                log.warning("%s: close: %s", self.DEVICE, e)
        self._disconnect()

    def _disconnect(self) -> None:
        self._stop_watchdog()
        if self._hb_timer is not None:
            self._hb_timer.cancel()
            self._hb_timer = None
        if self._network is not None:
            self.network.disconnect()
            self._network = None

    def __enter__(self) -> VibrationTableServo:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- state and supervision --------------------------------------------------------

    @property
    def state(self) -> str:
        """402 state from the last statusword received ('UNKNOWN' before the first, or with no link)."""
        if self._network is None or not self._tpdo.seq(0x6041):
            return "UNKNOWN"
        return state_of(self._tpdo.latest(0x6041))

    def check(self) -> None:
        """Raise the latched link error (BusOff, DeviceTimeout) or drive fault, if any; Disconnected if not open."""
        if self._network is None:
            raise Disconnected(self.DEVICE, "not connected (a reopen failed, or closed): reset, then retry")
        with self._err_lock:
            err = self._link_error or self._fault
        if err is not None:
            raise err

    def watch(self, duration_s: float) -> None:
        """Supervise the drive for duration_s; raise the first error as soon as it is latched."""
        self._error_event.wait(timeout_s=duration_s)
        self.check()

    def _latch(self, err: DriverError) -> None:
        with self._err_lock:
            if isinstance(err, DeviceFault):
                self._fault = self._fault or err
            else:
                self._link_error = self._link_error or err
            self._error_event.set()

    def _on_emcy(self, emcy: EmcyError) -> None:
        if emcy.code & 0xFF00 == 0:  # error reset
            return
        self._latch(
            DeviceFault(
                self.DEVICE,
                f"drive fault: {emcy.get_desc() or 'unknown'} (error register "
                f"0x{emcy.register:02X}); reset_fault() after removing the cause",
                field="EMCY",
                value=f"0x{emcy.code:04X}",
            )
        )

    def _on_heartbeat(self, nmt_state: int) -> None:
        with self._watchdog_lock:
            self._hb_last_link_s = self._link.now_s()
            if self._watching and self._watchdog is None:  # an armed deadline moves itself on when due (cheaper)
                self._arm_watchdog()
        self._hb_heard.set()

    def _produce_heartbeat(self) -> None:
        """One master heartbeat, if master_alive() holds; silent otherwise."""
        try:
            if self.master_alive():
                self.network.send_message(0x700 + MASTER_NODE_ID, bytes([0x05]))
        except (can.CanError, RuntimeError, AttributeError, Disconnected) as e:  # bus gone or network closed
            log.warning("%s: master heartbeat not sent: %s", self.DEVICE, e)

    def _configure_master_loss(self) -> None:
        """0x6007 and 0x605A written, then read back: the drive must stop on its own if the master is lost."""
        for index, value, meaning in (
            (0x6007, ABORT_CONNECTION_OPTION, "abort connection option: fault signal"),
            (0x605A, QUICK_STOP_OPTION, "quick stop option: quick-stop ramp, then SWITCH ON DISABLED"),
        ):
            self._sdo_write(index, value)
            got = self._sdo_read(index)
            if got != value:
                raise DeviceFault(
                    self.DEVICE,
                    "the drive did not keep the option written",
                    field=f"0x{index:04X}",
                    value=got,
                    allowed=f"{value} ({meaning})",
                )

    def master_loss_options(self) -> dict[str, int]:
        """0x6007 and 0x605A as the drive holds them now (SDO reads)."""
        return {"0x6007": self._sdo_read(0x6007), "0x605A": self._sdo_read(0x605A)}

    def _arm_watchdog(self) -> None:
        """The heartbeat watchdog: a deadline timer at the last heartbeat + the timeout; when it falls due with a
        later heartbeat heard, it is armed again from that one (hold _watchdog_lock)."""
        if self._watchdog is not None:
            self._watchdog.cancel()
        self._watchdog = self._link.call_at(self._hb_last_link_s + self._hb_timeout_s, self._heartbeat_overdue)

    def _stop_watchdog(self) -> None:
        with self._watchdog_lock:
            self._watching = False
            if self._watchdog is not None:
                self._watchdog.cancel()
                self._watchdog = None

    def _heartbeat_overdue(self) -> None:
        """No heartbeat for HEARTBEAT_FACTOR periods: latch BusOff (the TPDOs are silent too) or a lost
        heartbeat, and send a quick stop; once."""
        with self._watchdog_lock:
            now_s = self._link.now_s()
            silent_s = now_s - self._hb_last_link_s
            self._watchdog = None
            if not self._watching:
                return  # closed while this timer fell due
            # against the deadline as armed: now - last may fall a rounding error short of the timeout
            if now_s < self._hb_last_link_s + self._hb_timeout_s:
                self._arm_watchdog()  # heartbeats came in since it was armed
                return
            self._watching = False
            allowed = f"<= {self._hb_timeout_s * 1000:.0f} ms ({HEARTBEAT_FACTOR} periods)"
            if now_s - self._tpdo.last_rx_link_s > self._pdo_silence_s:
                err: DriverError = BusOff(
                    self.DEVICE,
                    "node silent (no heartbeat, no TPDO): bus-off or cable cut",
                    field="silence_ms",
                    value=round(silent_s * 1000),
                    allowed=allowed,
                )
            else:
                err = DeviceTimeout(
                    self.DEVICE,
                    "drive heartbeat lost (TPDOs still arriving)",
                    field="heartbeat_silence_ms",
                    value=round(silent_s * 1000),
                    allowed=allowed,
                )
        self._latch(err)
        log.error("%s; quick stop sent", err)
        try:
            self._send_controlword(CW_QUICK_STOP)
        except DriverError as e:
            log.error("%s: quick stop after heartbeat loss failed: %s", self.DEVICE, e)

    # ---- commands ---------------------------------------------------------------------

    def enable(self) -> None:
        """SWITCH ON DISABLED -> READY TO SWITCH ON -> SWITCHED ON -> OPERATION ENABLED.

        Each step is confirmed by the statusword; a faulted drive needs reset_fault() first.
        """
        self.check()
        sw = self._fresh_statusword()
        state = state_of(sw)
        if state == "OPERATION ENABLED":
            return
        if sw & SW_FAULT:
            raise DeviceFault(
                self.DEVICE,
                "drive in FAULT; reset_fault() first",
                field="statusword",
                value=f"0x{sw:04X}",
            )
        starts = {"SWITCH ON DISABLED": 0, "READY TO SWITCH ON": 1, "SWITCHED ON": 2}
        if state not in starts:
            raise InterlockError(
                self.DEVICE,
                "cannot enable from this state",
                field="state",
                value=state,
                allowed=", ".join(starts),
            )
        self._sdo_write(0x60FF, 0)  # no jump to a stale target velocity
        for cw, expected in _ENABLE_PATH[starts[state] :]:
            self._transition(cw, expected)

    def disable(self) -> None:
        """Ramp the crank to rest, then remove power (SWITCH ON DISABLED)."""
        self.check()
        if self.state == "OPERATION ENABLED":
            self.stop()
        self._transition(CW_DISABLE_VOLTAGE, "SWITCH ON DISABLED")

    def set_frequency(
        self, freq_hz: float, ramp_hz_per_s: float | None = None, *, wait: bool = True
    ) -> ServoReading | None:
        """Ramp the crank to freq_hz; with wait, return the first reading at speed.

        Limits are checked first (LimitError, nothing sent); the drive must be enabled.
        """
        ramp = self._limits.ramp_max_hz_per_s if ramp_hz_per_s is None else ramp_hz_per_s
        self._limits.check(self.DEVICE, freq_hz, ramp)
        return self._command(freq_hz, ramp, wait=wait)

    def stop(self, ramp_hz_per_s: float | None = None) -> ServoReading:
        """Ramp the crank to rest (profile deceleration) and wait until it is there."""
        ramp = self._limits.ramp_max_hz_per_s if ramp_hz_per_s is None else ramp_hz_per_s
        self._limits.check_ramp(self.DEVICE, ramp)
        at_rest = self._command(0.0, ramp, wait=True)
        assert at_rest is not None  # wait=True
        return at_rest

    def quick_stop(self) -> ServoReading:
        """Emergency stop: quick stop (0x6085 deceleration), sent without precondition, and waited for until the
        crank reads zero, whatever error is latched (a lost heartbeat, a fault: the TPDOs still tell the speed);
        DeviceTimeout only if the speed cannot be seen reaching zero within the quick-stop ramp + RAMP_MARGIN_S."""
        seq = self._tpdo.seq(0x606C)
        self._send_controlword(CW_QUICK_STOP)
        timeout_s = abs(self._actual_hz()) / self._qs_decel_hz_per_s + RAMP_MARGIN_S
        return self._wait_speed(0.0, seq, timeout_s, _at_rest_stopped, supervised=False)

    def reset_fault(self, timeout_s: float = FAULT_RESET_TIMEOUT_S) -> None:
        """Fault reset (rising edge of controlword bit 7), confirmed by the statusword.

        Confirmed means a statusword received after the reset has the fault bit clear
        (0x603F may keep the last error code on some drives, so it is not the criterion).
        The drive is left in SWITCH ON DISABLED; enable() again to move.
        """
        with self._err_lock:
            if self._link_error is not None:
                raise self._link_error
        self._send_controlword(CW_DISABLE_VOLTAGE)
        seq = self._tpdo.seq(0x6041)
        self._send_controlword(CW_FAULT_RESET)
        deadline_s = self._link.now_s() + timeout_s
        sw = None
        while True:
            remaining_s = deadline_s - self._link.now_s()
            got = self._tpdo.reception(0x6041, seq, timeout_s=max(remaining_s, 0.0))
            if got is not None:
                sw, seq = got.value, got.seq
                if not sw & SW_FAULT:
                    break
            if got is None or remaining_s <= 0:
                code = self._sdo_read(0x603F)
                raise DeviceFault(
                    self.DEVICE,
                    f"fault did not clear within {timeout_s:g} s of a fault reset (0x603F error code 0x{code:04X})",
                    field="statusword",
                    value=None if sw is None else f"0x{sw:04X}",
                    allowed="fault bit 3 clear",
                )
        with self._err_lock:
            self._fault = None
            if self._link_error is None:
                self._error_event.clear()
        self.node.emcy.reset()

    def read(self) -> ServoReading:
        """The next TPDO sample of velocity and position (waits at most one TPDO timeout)."""
        self.check()
        return self._reading(self._fresh(0x606C, self._tpdo.seq(0x606C), "velocity TPDO"))

    def read_error_code(self) -> int:
        """0x603F, the drive's last error code (SDO, retried once)."""
        return self._sdo_read(0x603F)

    # ---- internals --------------------------------------------------------------------

    def _set_tpdo_event_timers(self) -> None:
        """The station file's TPDO event timer on every enabled TPDO (CiA 301 0x1800+n sub 5: the master sets the
        rate it needs), written where the drive's differs."""
        event_timer_ms = self._cfg.tpdo_event_timer_ms
        for tpdo in self.node.tpdo.values():
            if tpdo.enabled and tpdo.event_timer != event_timer_ms:
                self._sdo_write(tpdo.com_record.od.index, event_timer_ms, subindex=5)
                tpdo.event_timer = event_timer_ms

    def _select_profile_velocity(self) -> None:
        supported = self._sdo_read(0x6502)
        if not supported & SUPPORTED_MODE_PV_BIT:
            raise DeviceFault(
                self.DEVICE,
                "profile velocity mode not supported",
                field="0x6502 supported drive modes",
                value=f"0x{supported:08X}",
                allowed="bit 2 set",
            )
        seq = self._tpdo.seq(0x6061)
        mode_var = cast(Any, self.node.rpdo_pointers[0x6060])  # a PDO variable (canopen types it as the map)
        with self._cw_lock:
            mode_var.raw = MODE_PROFILE_VELOCITY
            self._transmit(mode_var.pdo_parent)
        deadline_s = self._link.now_s() + STATE_TIMEOUT_S
        while self._link.now_s() < deadline_s:
            got = self._tpdo.reception(0x6061, seq, timeout_s=deadline_s - self._link.now_s())
            if got is None:
                break
            if got.value == MODE_PROFILE_VELOCITY:
                return
            seq = got.seq
        display = self._sdo_read(0x6061)  # the drive's word, not a stale TPDO
        if display != MODE_PROFILE_VELOCITY:
            raise DeviceFault(
                self.DEVICE,
                f"mode of operation not confirmed within {STATE_TIMEOUT_S:g} s",
                field="0x6061 modes of operation display",
                value=display,
                allowed=f"{MODE_PROFILE_VELOCITY} (profile velocity)",
            )

    def _check_pdo_mapping(self) -> None:
        missing = [i for i in TPDO_OBJECTS if i not in self.node.tpdo_pointers]
        missing += [i for i in RPDO_OBJECTS if i not in self.node.rpdo_pointers]
        if missing:
            raise DriverError(
                self.DEVICE,
                "drive PDO mapping differs from the EDS",
                field="unmapped objects",
                value=[f"0x{i:04X}" for i in missing],
                allowed="TPDO: 6041 6061 606C 6064, RPDO: 6040 6060",
            )

    def _command(self, freq_hz: float, ramp_hz_per_s: float, *, wait: bool) -> ServoReading | None:
        self.check()
        state = self.state
        if state != "OPERATION ENABLED":
            raise InterlockError(
                self.DEVICE,
                "drive not enabled; enable() first",
                field="state",
                value=state,
                allowed="OPERATION ENABLED",
            )
        seq = self._tpdo.seq(0x606C)
        from_hz = self._actual_hz()
        accel = round(ramp_hz_per_s / ACCEL_UNIT_HZ_PER_S)
        self._sdo_write(0x6083, accel)
        self._sdo_write(0x6084, accel)
        self._sdo_write(0x60FF, round(freq_hz / VELOCITY_UNIT_HZ))
        if not wait:
            return None
        timeout_s = abs(freq_hz - from_hz) / ramp_hz_per_s + RAMP_MARGIN_S
        return self._wait_speed(freq_hz, seq, timeout_s, _target_reached)

    def _wait_speed(
        self, freq_hz: float, seq: int, timeout_s: float, done: Callable[[int], bool], *, supervised: bool = True
    ) -> ServoReading:
        """Wait for a velocity TPDO within AT_SPEED_TOL_HZ of freq_hz with done(statusword); supervised: a latched
        error ends the wait at once."""
        deadline_s = self._link.now_s() + timeout_s
        actual_hz = None
        while True:
            remaining_s = deadline_s - self._link.now_s()
            got = self._tpdo.reception(0x606C, seq, timeout_s=max(remaining_s, 0.0))
            if supervised:
                self.check()
            if got is not None:
                seq = got.seq
                actual_hz = got.value * VELOCITY_UNIT_HZ
                near = abs(actual_hz - freq_hz) <= AT_SPEED_TOL_HZ
                if near and done(self._tpdo.latest(0x6041)):
                    return self._reading(got)
            if got is None or remaining_s <= 0:
                raise DeviceTimeout(
                    self.DEVICE,
                    f"crank not at {freq_hz:g} Hz within {timeout_s:.2f} s",
                    field="freq_hz",
                    value=actual_hz,
                    allowed=f"{freq_hz:g} +- {AT_SPEED_TOL_HZ:g} Hz",
                )

    def _actual_hz(self) -> float:
        return self._tpdo.latest(0x606C) * VELOCITY_UNIT_HZ

    def _reading(self, velocity: Reception) -> ServoReading:
        """Velocity and position of one instant: from the velocity's own TPDO where it carries the position (a TPDO
        that came after would pair one instant's velocity and time stamp with a later position)."""
        freq_hz = velocity.value * VELOCITY_UNIT_HZ
        counts = velocity.together.get(0x6064)
        position_rad = (self._tpdo.latest(0x6064) if counts is None else counts) * TWO_PI / POSITION_UNITS_PER_REV
        return ServoReading(velocity.t_s, freq_hz, TWO_PI * freq_hz, position_rad)

    def _transition(self, cw: int, expected: str) -> None:
        seq = self._tpdo.seq(0x6041)
        self._send_controlword(cw)
        deadline_s = self._link.now_s() + STATE_TIMEOUT_S
        state = "UNKNOWN"
        while (remaining_s := deadline_s - self._link.now_s()) > 0:
            got = self._tpdo.reception(0x6041, seq, timeout_s=remaining_s)
            if got is None:
                break
            sw, seq = got.value, got.seq
            state = state_of(sw)
            if state == expected:
                return
            if sw & SW_FAULT:
                self.check()
                raise DeviceFault(
                    self.DEVICE,
                    f"drive faulted on the way to {expected}",
                    field="statusword",
                    value=f"0x{sw:04X}",
                )
        self.check()
        raise DeviceTimeout(
            self.DEVICE,
            f"state not confirmed within {STATE_TIMEOUT_S:g} s after controlword 0x{cw:04X}",
            field="state",
            value=state,
            allowed=expected,
        )

    def _fresh_statusword(self) -> int:
        return self._fresh(0x6041, self._tpdo.seq(0x6041), "statusword TPDO").value

    def _fresh(self, index: int, after_seq: int, what: str) -> Reception:
        """The next reception of a TPDO-mapped object: due within one event period, the reply timeout on top."""
        wait_s = self._cfg.tpdo_event_timer_ms / 1000 + self._cfg.timeout_s
        got = self._tpdo.reception(index, after_seq, timeout_s=wait_s)
        if got is None:
            self.check()
            raise DeviceTimeout(
                self.DEVICE,
                f"no {what} within {wait_s:g} s",
                field=f"0x{index:04X}",
                value=None,
                allowed="cyclic TPDOs",
            )
        return got

    def _send_controlword(self, cw: int) -> None:
        if self._network is None or self._node is None:
            raise Disconnected(self.DEVICE, f"controlword 0x{cw:04X} not sent: not connected")
        var = cast(Any, self.node.rpdo_pointers[0x6040])  # a PDO variable (canopen types it as the map)
        with self._cw_lock:
            var.raw = cw
            self._transmit(var.pdo_parent)

    def _transmit(self, pdo_map: PdoMap) -> None:
        try:
            pdo_map.transmit()
        except can.CanError as e:
            raise Disconnected(self.DEVICE, f"CAN send of {pdo_map.name} failed: {e}") from e

    def _sdo_read(self, index: int, subindex: int | None = None) -> Any:
        var = self.node.sdo[index] if subindex is None else self.node.sdo[index][subindex]
        for attempt in range(1, READ_ATTEMPTS + 1):
            try:
                return var.raw
            except SdoAbortedError as e:
                raise DeviceFault(self.DEVICE, f"SDO read refused: {e}", field=f"0x{index:04X}", value=None) from e
            except SdoCommunicationError as e:
                log.warning("%s: SDO read 0x%04X attempt %d: %s", self.DEVICE, index, attempt, e)
                last = e
            except can.CanError as e:
                raise Disconnected(self.DEVICE, f"CAN send failed: {e}") from e
        self.check()
        raise DeviceTimeout(
            self.DEVICE,
            f"no SDO answer ({READ_ATTEMPTS} attempts of {self._cfg.timeout_s:g} s): {last}",
            field=f"0x{index:04X}",
            value=None,
            allowed="an SDO response",
        )

    def _sdo_write(self, index: int, value: int, subindex: int | None = None) -> None:
        """One confirmed SDO download; never retried (it may be a motion command)."""
        var = self.node.sdo[index] if subindex is None else self.node.sdo[index][subindex]
        try:
            var.raw = value
        except SdoAbortedError as e:
            raise DeviceFault(self.DEVICE, f"drive refused the write: {e}", field=f"0x{index:04X}", value=value) from e
        except SdoCommunicationError as e:
            self.check()
            raise DeviceTimeout(
                self.DEVICE,
                f"no SDO answer within {self._cfg.timeout_s:g} s; not retried, "
                "the drive may or may not have applied it",
                field=f"0x{index:04X}",
                value=value,
                allowed="an SDO response",
            ) from e
        except can.CanError as e:
            raise Disconnected(self.DEVICE, f"CAN send failed: {e}") from e
