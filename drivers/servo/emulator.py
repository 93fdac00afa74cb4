"""Emulated vibration-table servo: a CiA 402 drive as a canopen LocalNode on a python-can bus.

The drive side of config/eds/vibration_table_servo.eds, in profile velocity
mode, turning a station.twin.crank.CrankModel. canopen's LocalNode only answers
SDOs; this module adds what a drive does on its own (see field notes):

- copies received RPDOs into its object dictionary (NMT OPERATIONAL only);
- transmits TPDOs from its object dictionary on their event timers
  (0x1800+n sub 5, re-read when PDO parameters are written), only in
  NMT OPERATIONAL;
- runs the 402 state machine (controlword 0x6040 -> statusword 0x6041), the mode
  of operation and its display (0x6060/0x6061), quick stop (option code 0x605A:
  1/2 decelerate on 0x6084/0x6085 then SWITCH ON DISABLED, 5/6 the same ramps then
  stay in QUICK STOP ACTIVE) and fault reset;
- produces its heartbeat (0x1017) and consumes the master's (0x1016 sub 1): when
  the master falls silent the drive does what 0x6007 (abort connection option)
  says: 0 nothing (the crank keeps turning: the EDS default, which is why the
  driver writes it), 1 fault (EMCY 0x8130, crank braked on 0x6085), 2 disable
  voltage (crank braked on 0x6084), 3 quick stop (as 0x605A says).

Two time bases: `clock` (the station clock, real or virtual) time-stamps everything
physical (crank commands, speed, phase); its link (`clock.link`, station.clock) times
the bus protocol (event timers, heartbeat consumer), like the driver's own timeouts.

No thread of its own: the drive acts in the threads that reach it (the bus's, for
SDOs, RPDOs and the master's heartbeat) and in timers of the link clock: one
`call_every` per TPDO event timer, and a deadline timer for the heartbeat consumer,
moved on by every master heartbeat heard. The end of a quick stop is computed from
the crank model whenever the drive's state is looked at (a statusword sent in a TPDO
or read by SDO, the next controlword), so every statusword is true at its instant.

The drive's feedback is assumed to carry the twin's frequency error: velocity
0x606C and position 0x6064 report crank motion / (1 + eps_f), i.e. what the
drive believes; only an independent sensor (the grating) sees the true motion.

Fault injection for tests: inject_fault, silence_sdo, silence_heartbeat,
ignore_master_heartbeat, go_bus_off, freeze_mode_display, ignore_option_writes.
"""

from __future__ import annotations

import logging
import math
import threading
from functools import partial
from pathlib import Path
from typing import Any, cast

import can
import canopen
from canopen.objectdictionary import ODVariable
from canopen.pdo import PdoMap
from canopen.sdo import SdoAbortedError

from drivers.config import ServoSection
from drivers.servo.protocol import (
    ACCEL_UNIT_HZ_PER_S,
    CW_FAULT_RESET,
    EMCY_HEARTBEAT_ERROR,
    FAULT,
    MODE_PROFILE_VELOCITY,
    OE,
    POSITION_UNITS_PER_REV,
    QSA,
    RTSO,
    SDO_ABORT_VALUE_INVALID,
    SDO_ABORT_VALUE_TOO_HIGH,
    SDO_ABORT_VALUE_TOO_LOW,
    SO,
    SOD,
    STATE_STATUSWORD,
    SW_REMOTE,
    SW_TARGET_REACHED,
    VELOCITY_UNIT_HZ,
)
from station.clock import Clock, TimerHandle
from station.twin.crank import CrankModel

log = logging.getLogger(__name__)

TWO_PI = 2.0 * math.pi
SUPPORTED_MODES = (0, MODE_PROFILE_VELOCITY)
ABORT_OPTIONS = (0, 1, 2, 3)  # 0x6007 values this drive implements
QUICK_STOP_OPTIONS = (1, 2, 5, 6)  # 0x605A values this drive implements


def next_state(state: str, cw: int, prev_cw: int) -> str:
    """CiA 402 device control: the state a controlword leads to (quick stop option 2)."""
    if state == FAULT:
        rising = cw & CW_FAULT_RESET and not prev_cw & CW_FAULT_RESET
        return SOD if rising else state
    if not cw & 0x02:  # disable voltage: transitions 7, 9, 10, 12
        return SOD
    if not cw & 0x04:  # quick stop: transitions 7, 10, 11
        return {OE: QSA, RTSO: SOD, SO: SOD}.get(state, state)
    low = cw & 0x0F
    if low == 0x06 and state in (SOD, SO, OE):  # shutdown: 2, 6, 8
        return RTSO
    if low == 0x07 and state in (RTSO, OE):  # switch on / disable operation: 3, 5
        return SO
    if low == 0x0F and state in (RTSO, SO):  # enable operation: 3 + 4, 4
        return OE
    return state


def error_register(code: int) -> int:
    """CiA 301 error register 0x1001 for an EMCY code: generic bit plus the class bit."""
    return 0x01 | {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10}.get(code >> 12, 0)


class ServoEmulator:
    """The drive; start() joins the bus, stop() leaves it. Thread-safe."""

    def __init__(
        self,
        *,
        channel: str,
        node_id: int,
        eds_path: Path,
        clock: Clock,
        crank: CrankModel | None = None,
        interface: str = "virtual",
    ) -> None:
        self.channel = channel
        self.node_id = node_id
        self.interface = interface
        self._eds_path = Path(eds_path)
        self._clock = clock
        self._bus_clock = clock.link
        self.crank = crank if crank is not None else CrankModel(t0_s=clock.now_s())
        self._lock = threading.RLock()
        self._running = False  # timers act only while the emulator runs
        self._network: canopen.Network | None = None
        self._node: canopen.LocalNode | None = None
        # 402 device state
        self._state = SOD
        self._cw = 0
        self._mode_display = 0
        self._error_code = 0
        self._error_register = 0
        self._fault_persistent = False
        self._params: dict[int, int] = {}  # 0x60FF, 0x607F, 0x6083, 0x6084, 0x6085, 0x6007, 0x605A
        # bus-side state (timers of the link clock)
        self._event_timer_s: dict[int, float] = {}
        self._tpdo_timers: list[TimerHandle] = []
        self._hb_master_id = 0
        self._hb_timeout_s = 0.0
        self._hb_last_s: float | None = None
        self._hb_deadline: TimerHandle | None = None
        # injected faults
        self._sdo_silent = False
        self._master_hb_ignored = False
        self._bus_off = False
        self._mode_frozen = False
        self._options_frozen = False

    @classmethod
    def from_config(cls, servo: ServoSection, clock: Clock, crank: CrankModel | None = None) -> ServoEmulator:
        return cls(
            channel=servo.channel,
            node_id=servo.node_id,
            eds_path=servo.eds,
            clock=clock,
            crank=crank,
            interface=servo.interface,
        )

    # ---- life cycle -------------------------------------------------------------------

    @property
    def node(self) -> canopen.LocalNode:
        """The emulated drive's node, while the emulator runs."""
        if self._node is None:
            raise RuntimeError("servo emulator: not started")
        return self._node

    @property
    def network(self) -> canopen.Network:
        if self._network is None:
            raise RuntimeError("servo emulator: not started")
        return self._network

    def start(self) -> None:
        bus = can.Bus(interface=self.interface, channel=self.channel)
        self._network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.05  # a prompt stop()
        self.network.connect()
        node = self.network.create_node(self.node_id, str(self._eds_path))
        self._node = node
        node.add_read_callback(self._on_read)
        node.add_write_callback(self._on_write)
        for index in (0x60FF, 0x607F, 0x6083, 0x6084, 0x6085, 0x6007, 0x605A):
            self._params[index] = int(cast(Any, node.sdo[index]).raw)
        with self._lock:
            self._running = True
            self._configure_consumer(int(cast(Any, node.sdo)[0x1016][1].raw))
            self._load_pdo_config()
        node.nmt.state = "INITIALISING"  # boot-up message
        node.nmt.state = "PRE-OPERATIONAL"  # starts the heartbeat producer (0x1017)

    def stop(self) -> None:
        with self._lock:  # a timer running now finishes first; none acts afterwards
            self._running = False
            self._cancel_tpdo_timers()
            self._cancel_consumer()
        if self._network is not None:
            self.node.nmt.stop_heartbeat()
            self.network.disconnect()
            self._network = None

    def __enter__(self) -> ServoEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- inspection -------------------------------------------------------------------

    @property
    def state(self) -> str:
        """The 402 state, e.g. 'OPERATION ENABLED'."""
        with self._lock:
            self._settle(self._clock.now_s())
            return self._state

    @property
    def nmt_state(self) -> str:
        return self.node.nmt.state

    # ---- fault injection --------------------------------------------------------------

    def inject_fault(self, code: int = 0x2310, *, persistent: bool = False) -> None:
        """A drive fault: EMCY, 0x603F, statusword fault bit; crank brought to rest.

        A persistent fault survives fault resets (its cause is still there).
        """
        with self._lock:
            self._settle(self._clock.now_s())
            self._fault_persistent = persistent
            self._enter_fault(code)

    def silence_sdo(self) -> None:
        """Stop answering SDO requests (PDOs and heartbeat go on)."""
        with self._lock:
            if not self._sdo_silent:
                self._sdo_silent = True
                self.network.unsubscribe(self.node.sdo.rx_cobid, self.node.sdo.on_request)

    def silence_heartbeat(self) -> None:
        """Stop producing the heartbeat (everything else goes on)."""
        self.node.nmt.stop_heartbeat()

    def ignore_master_heartbeat(self) -> None:
        """Stop hearing the master's heartbeat, as if its frames were lost on the way."""
        with self._lock:
            self._master_hb_ignored = True

    def go_bus_off(self) -> None:
        """Leave the bus (simulated CAN bus-off): no frame is sent or received any more.

        The heartbeat consumer still runs, so the drive faults and stops the crank.
        """
        with self._lock:
            self._bus_off = True
        self.silence_sdo()
        self.silence_heartbeat()

    def ignore_option_writes(self) -> None:
        """0x6007 and 0x605A writes are acknowledged but not kept (a drive that ignores the master's settings)."""
        with self._lock:
            self._options_frozen = True

    @property
    def master_loss_options(self) -> tuple[int, int]:
        """(0x6007, 0x605A) as the drive holds them."""
        with self._lock:
            return self._params[0x6007], self._params[0x605A]

    def freeze_mode_display(self) -> None:
        """0x6061 no longer follows 0x6060 (a mode switch that silently fails)."""
        with self._lock:
            self._mode_frozen = True

    # ---- object dictionary callbacks (run in the thread that delivers the frame) --------

    def _on_read(self, index: int, subindex: int, od: ODVariable) -> int | None:
        with self._lock:
            t_s = self._clock.now_s()
            self._settle(t_s)
            if index == 0x6041:
                return self._statusword(t_s)
            if index == 0x6061:
                return self._mode_display
            if index == 0x603F:
                return self._error_code
            if index == 0x1001:
                return self._error_register
            if index in (0x6007, 0x605A) and index in self._params:
                return self._params[index]
            belief = 1.0 + self.crank.eps_f
            if index == 0x606C:
                return round(self.crank.speed_radps(t_s) / belief / TWO_PI / VELOCITY_UNIT_HZ)
            if index == 0x6064:
                counts = round(self.crank.phase_rad(t_s) / belief / TWO_PI * POSITION_UNITS_PER_REV)
                return (counts + 2**31) % 2**32 - 2**31
        return None

    def _on_write(self, index: int, subindex: int, od: ODVariable, data: bytes) -> None:
        """Validate and apply a write (SDO download or copied RPDO) before LocalNode stores it."""
        if 0x1400 <= index < 0x1C00:
            with self._lock:
                self.node.data_store.setdefault(index, {})[subindex] = bytes(data)
                if self._running:
                    try:  # new mappings, cob ids and event timers take effect at once
                        self._load_pdo_config()
                    except Exception:  # a half-written mapping: the write is kept, the drive lives on
                        log.exception("servo emulator: PDO configuration not loaded after writing 0x%04X", index)
            return
        value = od.decode_raw(data)
        if not isinstance(value, int):
            return  # every object this drive acts on is an integer (the EDS); others are only stored
        if od.min is not None and value < od.min:
            raise SdoAbortedError(SDO_ABORT_VALUE_TOO_LOW)
        if od.max is not None and value > od.max:
            raise SdoAbortedError(SDO_ABORT_VALUE_TOO_HIGH)
        with self._lock:
            t_s = self._clock.now_s()
            self._settle(t_s)
            if index == 0x6040:
                self._on_controlword(value, t_s)
            elif index == 0x6060:
                self._on_mode(value, t_s)
            elif index == 0x60FF:
                if abs(value) > self._params[0x607F]:
                    raise SdoAbortedError(SDO_ABORT_VALUE_TOO_HIGH)
                self._params[index] = value
                self._command_velocity(t_s)
            elif index in (0x6083, 0x6084, 0x6085):
                self._params[index] = value
                self._command_velocity(t_s)
            elif index in (0x6007, 0x605A):
                if value not in (ABORT_OPTIONS if index == 0x6007 else QUICK_STOP_OPTIONS):
                    raise SdoAbortedError(SDO_ABORT_VALUE_INVALID)
                if not self._options_frozen:
                    self._params[index] = value
            elif index == 0x1016 and subindex == 1:
                self._configure_consumer(value)

    def _on_rpdo(self, pdo_map: PdoMap) -> None:
        with self._lock:
            if self._bus_off or self.node.nmt.state != "OPERATIONAL":
                return
            for var in pdo_map:
                try:
                    self.node.set_data(var.index, var.subindex, var.get_data())
                except SdoAbortedError as e:
                    log.warning("servo emulator: RPDO value for 0x%04X refused: %s", var.index, e)

    def _on_master_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        with self._lock:
            if not (self._bus_off or self._master_hb_ignored):
                self._hb_last_s = self._bus_clock.now_s()
                if self._hb_deadline is None:  # a deadline armed stays: it moves itself on when due (cheaper)
                    self._arm_consumer()

    # ---- device behaviour (called with the lock held) ---------------------------------

    def _settle(self, t_s: float) -> None:
        """Quick stop option 1 or 2: once the crank is at rest, QUICK STOP ACTIVE -> SWITCH ON DISABLED."""
        if self._state == QSA and self._params[0x605A] in (1, 2) and self.crank.at_speed(t_s):
            self._state = SOD

    def _statusword(self, t_s: float) -> int:
        sw = STATE_STATUSWORD[self._state] | SW_REMOTE
        pv = self._state == OE and self._mode_display == MODE_PROFILE_VELOCITY
        if pv and self.crank.at_speed(t_s):
            sw |= SW_TARGET_REACHED
        return sw

    def _on_controlword(self, cw: int, t_s: float) -> None:
        prev, self._cw = self._cw, cw
        if self._state == FAULT and self._fault_persistent:
            return
        new = next_state(self._state, cw, prev)
        if new == self._state:
            return
        if self._state == FAULT:
            self._error_code = self._error_register = 0
            if not self._bus_off:
                self.node.emcy.reset()
        self._state = new
        self._command_velocity(t_s)

    def _on_mode(self, mode: int, t_s: float) -> None:
        if mode not in SUPPORTED_MODES:
            raise SdoAbortedError(SDO_ABORT_VALUE_INVALID)
        if not self._mode_frozen and mode != self._mode_display:
            self._mode_display = mode
            self._command_velocity(t_s)

    def _command_velocity(self, t_s: float) -> None:
        """Profile velocity when enabled in mode 3; otherwise brake to rest on 0x6085
        (on 0x6084 in a quick stop with option 1 or 5)."""
        if self._state == OE and self._mode_display == MODE_PROFILE_VELOCITY:
            w_radps = TWO_PI * self._params[0x60FF] * VELOCITY_UNIT_HZ
            speeding_up = abs(w_radps) >= abs(self.crank.speed_radps(t_s))
            accel = self._params[0x6083 if speeding_up else 0x6084]
        elif self._state == QSA and self._params[0x605A] in (1, 5):
            w_radps, accel = 0.0, self._params[0x6084]
        else:
            w_radps, accel = 0.0, self._params[0x6085]
        self.crank.command_speed(w_radps, TWO_PI * accel * ACCEL_UNIT_HZ_PER_S, t_s)

    def _enter_fault(self, code: int) -> None:
        self._error_code = code
        self._error_register = error_register(code)
        self._state = FAULT
        self._command_velocity(self._clock.now_s())
        if not self._bus_off:
            self.node.emcy.send(code, self._error_register)

    def _configure_consumer(self, value: int) -> None:
        """0x1016 sub 1: master node id in bits 16-23, time in ms in bits 0-15."""
        if self._hb_master_id:
            self.network.unsubscribe(0x700 + self._hb_master_id, self._on_master_heartbeat)
        master_id, time_ms = (value >> 16) & 0x7F, value & 0xFFFF
        self._hb_master_id = master_id if time_ms else 0
        self._hb_timeout_s = time_ms / 1000.0
        self._hb_last_s = None  # monitoring starts with the first heartbeat heard
        self._cancel_consumer()
        if self._hb_master_id:
            self.network.subscribe(0x700 + self._hb_master_id, self._on_master_heartbeat)

    def _load_pdo_config(self) -> None:
        """(Re)read PDO parameters and mappings from the local object dictionary."""
        node = cast(Any, self.node)  # canopen types the PDO maps as optional
        node.tpdo.read()
        node.rpdo.read()
        for rpdo in node.rpdo.map.values():
            if self._on_rpdo not in rpdo.callbacks:
                rpdo.add_callback(self._on_rpdo)
        self._event_timer_s = {
            n: (tpdo.event_timer or 0) / 1000.0
            for n, tpdo in node.tpdo.map.items()
            if tpdo.enabled and tpdo.trans_type in (254, 255)
        }
        self._cancel_tpdo_timers()
        self._tpdo_timers = [
            self._bus_clock.call_every(period_s, partial(self._on_event_timer, n))
            for n, period_s in self._event_timer_s.items()
            if period_s > 0
        ]

    # ---- timers of the link clock ------------------------------------------------------

    def _cancel_tpdo_timers(self) -> None:
        for timer in self._tpdo_timers:
            timer.cancel()
        self._tpdo_timers = []

    def _on_event_timer(self, n: int) -> None:
        """TPDO n's event timer: transmit it in NMT OPERATIONAL, unless off the bus."""
        with self._lock:
            if not self._running or self._bus_off or self.node.nmt.state != "OPERATIONAL":
                return
            tpdo = cast(Any, self.node.tpdo).map.get(n)
            if tpdo is not None:
                self._transmit_tpdo(tpdo)

    def _transmit_tpdo(self, tpdo: PdoMap) -> None:
        """Fill the TPDO from the object dictionary as it reads now (LocalNode does not: field notes) and send it.
        A byte-aligned object's bytes go straight into the frame: `PdoVariable.set_data` formats its debug line
        (the PDO's name, a hex dump) whether or not anything logs it: 5 % of a station's CPU at rest (BENCHMARKS.md)."""
        for var in tpdo:
            data, offset = self.node.get_data(var.index, var.subindex), var.offset
            if offset is None or offset % 8 or var.length % 8:
                var.set_data(data)
            else:
                tpdo.data[offset // 8 : offset // 8 + len(data)] = data
        tpdo.transmit()

    def _arm_consumer(self) -> None:
        """The heartbeat consumer's deadline: consumer time after the last master heartbeat heard (when it falls
        due with a later heartbeat heard, it is armed again from that one)."""
        self._cancel_consumer()
        if self._running and self._hb_master_id and self._hb_last_s is not None:
            self._hb_deadline = self._bus_clock.call_at(
                self._hb_last_s + self._hb_timeout_s, self._master_heartbeat_due
            )

    def _cancel_consumer(self) -> None:
        if self._hb_deadline is not None:
            self._hb_deadline.cancel()
            self._hb_deadline = None

    def _master_heartbeat_due(self) -> None:
        with self._lock:
            if not self._running or self._hb_last_s is None:
                return  # stopped, or the consumer was reconfigured while this timer fell due
            self._hb_deadline = None
            if self._bus_clock.now_s() < self._hb_last_s + self._hb_timeout_s:  # the deadline as armed, to the bit
                self._arm_consumer()  # heartbeats came in since it was armed: the deadline follows the last
                return
            self._master_heartbeat_lost()

    def _master_heartbeat_lost(self) -> None:
        """No master heartbeat for the consumer time: do what 0x6007 says."""
        self._settle(self._clock.now_s())
        self._hb_last_s = None
        option = self._params[0x6007]
        log.warning("servo emulator: master heartbeat lost; abort connection option 0x6007 = %d", option)
        if self._state == FAULT or option == 0:
            return
        if option == 1:
            self._enter_fault(EMCY_HEARTBEAT_ERROR)
            return
        self._state = SOD if option == 2 or self._state != OE else QSA
        t_s = self._clock.now_s()
        if option == 2:  # disable voltage: no torque; the crank runs down on the profile deceleration
            self.crank.command_speed(0.0, TWO_PI * self._params[0x6084] * ACCEL_UNIT_HZ_PER_S, t_s)
        else:
            self._command_velocity(t_s)
