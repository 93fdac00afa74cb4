"""Counter/timer board: integer-pulse timing windows on the instrument's output.

The board counts the PIGA's output pulses up/down and time-stamps with a
32-bit counter of 50 ns ticks (wraps every 214.7 s; a window lasts about
560 s). Armed with a preset P, it opens the window on the first output-pulse
edge, closes it on the P-th edge after that, and reports every reference
crossing (the read head's Z mark, psi = 0) from the opening until the first
crossing at or after the closing. Binary framing of `drivers.serial_port`
(sync A5 5A, type, u16 length, payload, CRC-16/CCITT), little-endian,
921600 baud.

Host -> board
    0x20 ARM      i32 preset P (1 .. 2^31-1), u8 flags (bit0: stream every edge)
    0x21 ABORT    (empty)
    0x22 STATUS?  (empty)
Board -> host
    0xA0 ACK       u8 command, u8 result (0 OK, 1 busy, 2 bad argument)
    0xA2 STATUS    u8 state, i32 preset, u32 ticks, u8 fault code
    0xB0 OPEN      u32 ticks                  window opened (t = 0)
    0xB1 REF       u32 n, u32 ticks           reference crossing n of this window
    0xB2 EDGES     u32 first index, u16 count, count x (u32 ticks, i8 direction)
    0xB3 CLOSE     u32 ticks, i32 pulses      window closed (signed count)
    0xB4 DONE      u32 crossings reported, u32 edges dropped (FIFO overflow)
    0xB5 HEARTBEAT u32 ticks, u8 state        every second of station time while not idle
    0xBF FAULT     u8 code (1 counter overflow), u32 ticks   the window is aborted
States: 0 idle, 1 armed, 2 counting, 3 closing (waiting for the closing crossing),
4 done, 5 fault.

The heartbeat keeps the 32-bit time stamps unambiguous through a static
window with no crossing for 560 s. Edge indices reveal edges dropped when the
stream outruns the line.

Errors: silence for `silence_s` -> DeviceTimeout; CRC -> ChecksumError;
truncated/garbled frame -> FrameError (resynchronised; a lost OPEN, CLOSE or
REF of the window under way then fails the window with FrameError, since its
timing can no longer be trusted); FAULT -> DeviceFault (field "pulse_count"
for overflow); bad preset -> LimitError (nothing sent); ARM is not retried,
STATUS?/ABORT are.
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Callable

import numpy as np

from drivers.counter_timer.protocol import (
    ABORT,
    ACK,
    ACK_PAYLOAD,
    ACK_RESULTS,
    ARM,
    ARM_PAYLOAD,
    CLOSE,
    CLOSE_PAYLOAD,
    DEVICE,
    DONE,
    DONE_PAYLOAD,
    EDGE_DTYPE,
    EDGES,
    EDGES_HEADER,
    FAULT,
    FAULT_PAYLOAD,
    FAULTS,
    FLAG_STREAM_EDGES,
    HEARTBEAT,
    HEARTBEAT_PAYLOAD,
    MAX_PRESET,
    OPEN,
    OPEN_PAYLOAD,
    REF,
    REF_PAYLOAD,
    STATES,
    STATUS,
    STATUS_PAYLOAD,
    STATUS_Q,
)
from drivers.errors import DeviceFault, DeviceTimeout, DriverError, FrameError, LimitError, ReplyLost
from drivers.serial_port import TICK_S, Frame, FramedDevice, TickUnwrapper
from station.clock import Clock
from station.engine.protocols import Event, WindowResult


class CounterTimer(FramedDevice):
    """Driver of the counter/timer board.

    `clock`: if given, the board's time base is the station clock's (as in the
    emulator) and time stamps are station seconds.
    """

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 921_600,
        timeout_s: float = 0.5,
        silence_s: float = 3.0,
        retries: int = 2,
        clock: Clock | None = None,
        max_preset: int = MAX_PRESET,
    ) -> None:
        super().__init__(port, baud, clock=clock)
        self.timeout_s = timeout_s
        self.silence_s = silence_s
        self.retries = retries
        self.max_preset = min(max_preset, MAX_PRESET)
        self._unwrap = TickUnwrapper(clock, absolute=clock is not None, sequential=True)
        self._window: WindowResult | None = None
        self._stream_edges = False
        self._refs: list[float] = []
        self._edge_t: list[np.ndarray] = []
        self._edge_d: list[np.ndarray] = []
        self._next_edge = 0
        self._next_ref = 0
        self._opened = False
        self._closed = False

    # ---- commands

    def _command(self, cmd: int, payload: bytes, *, retries: int, what: str) -> Frame:
        def is_reply(f: Frame) -> bool:
            if cmd == STATUS_Q:
                return f.type == STATUS and len(f.payload) == STATUS_PAYLOAD.size
            return f.type == ACK and f.payload[:1] == bytes([cmd])

        reply = self.framed.request(cmd, payload, is_reply, timeout_s=self.timeout_s, retries=retries, what=what)
        if reply.type == ACK:
            _, result = ACK_PAYLOAD.unpack(reply.payload)
            if result != 0:
                raise DeviceFault(
                    DEVICE,
                    f"{what} rejected: {ACK_RESULTS.get(result, result)}",
                    field="result",
                    value=result,
                )
        return reply

    def arm(self, preset_pulses: int, *, stream_edges: bool = False) -> None:
        """Arm a window of `preset_pulses` pulses (not retried: on a timeout the
        board's state is unknown; ask status() and abort() if needed)."""
        if not isinstance(preset_pulses, int) or not 1 <= preset_pulses <= self.max_preset:
            raise LimitError(
                DEVICE,
                "bad preset",
                field="preset_pulses",
                value=preset_pulses,
                allowed=f"1 .. {self.max_preset}",
            )
        self.framed.reset()
        flags = FLAG_STREAM_EDGES if stream_edges else 0
        self._window = WindowResult(preset_pulses)
        self._stream_edges = stream_edges
        self._refs, self._edge_t, self._edge_d = [], [], []
        self._next_edge = self._next_ref = 0
        self._opened = self._closed = False
        self._unwrap.reset()
        try:
            self._command(ARM, ARM_PAYLOAD.pack(preset_pulses, flags), retries=0, what="ARM")
        except DeviceTimeout as exc:  # a lost reply (a garbled frame): undone by abort(), so the point may repeat
            raise ReplyLost(DEVICE, f"{exc}; the board may be armed: abort() before arming again") from exc

    def abort(self) -> None:
        """Abort any window (idempotent, retried)."""
        self._command(ABORT, b"", retries=self.retries, what="ABORT")
        self._window = None

    def status(self) -> dict[str, object]:
        """Query (retried): state, preset, ticks, fault."""
        reply = self._command(STATUS_Q, b"", retries=self.retries, what="STATUS?")
        state, preset, ticks, fault = STATUS_PAYLOAD.unpack(reply.payload)
        return {
            "state": STATES.get(state, str(state)),
            "preset": preset,
            "ticks": ticks,
            "fault": FAULTS.get(fault, fault) if fault else None,
        }

    # ---- events

    def next_event(self) -> Event:
        """The next board event; DeviceTimeout after silence_s without any frame."""
        fp = self.framed
        deadline_s = self._link_clock.now_s() + self.silence_s
        while True:
            item = fp.poll_item()
            if item is None:
                left_s = deadline_s - self._link_clock.now_s()
                if left_s <= 0:
                    raise DeviceTimeout(DEVICE, f"board silent for {self.silence_s:g} s (no heartbeat)")
                fp.fill(left_s)
                continue
            if isinstance(item, FrameError):
                if self._window is not None and self._opened and not self._closed:
                    raise type(item)(DEVICE, f"window event may be lost, window timing not trusted ({item})") from item
                raise item
            event = self._decode(item)
            if event is not None:
                return event

    def _decode(self, f: Frame) -> Event | None:
        p = f.payload
        try:
            if f.type == HEARTBEAT:
                raw, state = HEARTBEAT_PAYLOAD.unpack(p)
                return Event("heartbeat", self._unwrap.unwrap_s(raw), state)
            if f.type == OPEN:
                (raw,) = OPEN_PAYLOAD.unpack(p)
                self._opened = True
                return Event("open", self._unwrap.unwrap_s(raw))
            if f.type == REF:
                n, raw = REF_PAYLOAD.unpack(p)
                if n != self._next_ref:
                    raise FrameError(DEVICE, f"reference crossing {self._next_ref} missing (got {n})")
                self._next_ref = n + 1
                return Event("ref", self._unwrap.unwrap_s(raw), n)
            if f.type == EDGES:
                first, count = EDGES_HEADER.unpack_from(p)
                edges = np.frombuffer(p, dtype=EDGE_DTYPE, count=count, offset=EDGES_HEADER.size)
                ticks = self._unwrap.unwrap_array(edges["ticks"])
                self._edge_t.append(ticks * TICK_S)
                self._edge_d.append(edges["dir"].astype(np.int8))
                if self._window is not None:
                    self._window.edges_lost += first - self._next_edge
                self._next_edge = first + count
                return Event("edges", float(ticks[-1] * TICK_S) if count else float("nan"), count)
            if f.type == CLOSE:
                raw, pulses = CLOSE_PAYLOAD.unpack(p)
                self._closed = True
                return Event("close", self._unwrap.unwrap_s(raw), pulses)
            if f.type == DONE:
                _n_refs, dropped = DONE_PAYLOAD.unpack(p)
                return Event("done", float("nan"), dropped)
            if f.type == FAULT:
                code, raw = FAULT_PAYLOAD.unpack(p)
                self._unwrap.unwrap_s(raw)
                self._window = None
                raise DeviceFault(
                    DEVICE,
                    f"{FAULTS.get(code, f'fault code {code}')}: window aborted",
                    field="pulse_count" if code == 1 else "fault",
                    value=code,
                )
        except (struct.error, ValueError) as exc:
            raise FrameError(DEVICE, f"bad payload in frame 0x{f.type:02X}: {exc}") from exc
        return None  # late ACK/STATUS or unknown frame

    def wait_window(
        self,
        *,
        timeout_s: float | None = None,
        on_event: Callable[[Event], None] | None = None,
    ) -> WindowResult:
        """Collect the armed window's events until DONE and return the result.

        Bounded: DeviceTimeout if the board falls silent (silence_s) or, when
        given, the whole wait exceeds timeout_s of link-clock time (the board is then
        left as it is: abort() it if wanted).
        """
        w = self._window
        if w is None:
            raise DriverError(DEVICE, "no window armed")
        deadline_s = None if timeout_s is None else self._link_clock.now_s() + timeout_s
        while True:
            if deadline_s is not None and self._link_clock.now_s() > deadline_s:
                raise DeviceTimeout(DEVICE, f"window not done within {timeout_s:g} s")
            ev = self.next_event()
            if on_event is not None:
                on_event(ev)
            if ev.kind == "open":
                w.open_s = ev.t_s
            elif ev.kind == "ref":
                self._refs.append(ev.t_s)
            elif ev.kind == "close":
                w.close_s, w.pulses = ev.t_s, ev.value
            elif ev.kind == "done":
                if not (self._opened and self._closed):
                    raise FrameError(DEVICE, "window done without its OPEN or CLOSE event")
                w.crossings_s = np.array(self._refs)
                if self._stream_edges:
                    w.edges_t_s = np.concatenate(self._edge_t) if self._edge_t else np.empty(0)
                    w.edges_dir = np.concatenate(self._edge_d) if self._edge_d else np.empty(0, np.int8)
                    w.edges_lost = max(w.edges_lost, ev.value)
                self._window = None
                return w

    def measure(self, preset_pulses: int, *, stream_edges: bool = False, **kw: object) -> WindowResult:
        """arm() then wait_window(); aborts the board if either fails (a lost ARM reply may leave it armed)."""
        try:
            self.arm(preset_pulses, stream_edges=stream_edges)
            return self.wait_window(**kw)  # type: ignore[arg-type]
        except DriverError:
            with contextlib.suppress(DriverError):
                self.abort()
            raise
