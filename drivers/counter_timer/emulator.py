"""Emulator of the counter/timer board (protocol in drivers.counter_timer.driver and .protocol).

ARM asks the world for the window (world.open_window at the arm time); each
poll then reports, for the station time elapsed since the previous poll, the
opening, the reference crossings (world.reference_crossings_s), the edges if
streaming (world.pulse_edges_s), the closing and, once the first crossing at
or after the closing is reported (or at once if the table is at rest), DONE.
A heartbeat goes out every second of station time while a window is under way.

Rate limit: edges are the bulky output. Each poll sends the edges that fit in
the transmit FIFO and drops the rest (their indices are skipped and the DONE
frame counts them), so a virtual clock faster than the line shows up as
edges_lost, never as a backlog. Events (OPEN/REF/CLOSE/DONE) are never
dropped: reference crossings that do not fit wait on the board (their time
stamps are already taken) and go out in order on the next polls, before the
CLOSE.

Faults: NO_ANSWER (commands ignored, `count` of them; silent while armed),
GARBLE / TRUNCATE / CRC_ERROR (next frame), LOST_REPLY (the next `count`
commands are carried out, their replies lost: an ARM so met leaves the board
armed), COUNTER_OVERFLOW (next window under way fails with FAULT code 1),
DISCONNECT.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drivers.counter_timer import protocol as c
from drivers.counter_timer.protocol import ARMED, CLOSING, COUNTING, DONE_STATE, FAULTED, IDLE
from drivers.pty_link import LINK_FAULTS, Fault, PtyEmulator, garble, truncate
from drivers.serial_port import FrameParser, encode_frame, ticks_of, ticks_of_array

SNAP_S = 25e-9  # half a 50 ns tick: edges this close to the window's boundary edges are those
CLOSING_LIMIT_S = 12.0  # give up waiting for a closing crossing (slowest table: 10 s period)
# On a sim:// line the board reports a window in batches this far apart (crossings, edges, heartbeats carry
# their own stamps), and at once when the window opens and closes; idle, it speaks only when spoken to.
# Each batch costs the host a wake-up (a fifth of a window's CPU at 0.25 s): crossings and the 1 s heartbeat
# go once a second; streamed pulse edges (they fill the 64 kB FIFO) and the wait for the closing
# crossing four times a second.
REPORT_BATCH_S = 1.0
EDGE_BATCH_S = 0.25
REF_FRAME_BYTES = 7 + c.REF_PAYLOAD.size
EVENT_RESERVE_BYTES = 256  # room kept for OPEN/CLOSE/DONE/HEARTBEAT/ACK frames
MAX_STAMP_GAP_S = 100.0  # consecutive stamps well within a wrap of the 32-bit tick counter (214.7 s)


class CounterEmulator(PtyEmulator):
    name = "counter-emulator"
    supported_faults = LINK_FAULTS | {Fault.COUNTER_OVERFLOW, Fault.LOST_REPLY}

    def __init__(self, world: Any, *, baud: int = 921_600, **kw: Any) -> None:
        super().__init__(world.clock, baud=baud, **kw)
        self.world = world
        self._rx = FrameParser("counter host")
        self.state = IDLE
        self.preset = 0
        self.stream_edges = False
        self.window: Any = None
        self.fault_code = 0
        self._last_s = 0.0
        self._last_heartbeat_s = 0.0
        self._n_refs = 0
        self._edge_index = 0
        self.edges_dropped = 0
        self._last_ref_s: float | None = None
        self._reply_lost = False  # the command being carried out loses its reply (Fault.LOST_REPLY)

    # ---- output

    def _frame(self, frame_type: int, payload: bytes) -> None:
        self._send_frame(encode_frame(frame_type, payload))

    def _send_frame(self, frame: bytes) -> None:
        """One encoded frame out, as an armed link fault leaves it."""
        if self._reply_lost:
            return
        if self.faults.take(Fault.GARBLE):
            frame = garble(frame)
        elif self.faults.take(Fault.TRUNCATE):
            frame = truncate(frame)
        elif self.faults.take(Fault.CRC_ERROR):
            frame = frame[:-1] + bytes([frame[-1] ^ 0x5A])
        self.send(frame)

    # ---- commands

    def on_bytes(self, data: bytes) -> None:
        self._rx.feed(data)
        while (item := self._rx.next_item()) is not None:
            if isinstance(item, Exception):
                continue
            if self.faults.take(Fault.NO_ANSWER):
                continue
            self._reply_lost = self.faults.take(Fault.LOST_REPLY)
            try:
                self._command(item.type, item.payload)
            finally:
                self._reply_lost = False

    def _ack(self, cmd: int, result: int) -> None:
        self._frame(c.ACK, c.ACK_PAYLOAD.pack(cmd, result))

    def _command(self, cmd: int, payload: bytes) -> None:
        now = self.clock.now_s()
        if cmd == c.ARM:
            if len(payload) != c.ARM_PAYLOAD.size:
                self._ack(cmd, 2)
                return
            preset, flags = c.ARM_PAYLOAD.unpack(payload)
            if self.state in (ARMED, COUNTING, CLOSING):
                self._ack(cmd, 1)
                return
            if preset < 1:
                self._ack(cmd, 2)
                return
            self.preset = preset
            self.stream_edges = bool(flags & c.FLAG_STREAM_EDGES)
            self.window = self.world.open_window(now, preset)
            self.state = ARMED
            self.fault_code = 0
            self._n_refs = self._edge_index = self.edges_dropped = 0
            self._last_ref_s = None
            self._last_heartbeat_s = now
            self._ack(cmd, 0)
        elif cmd == c.ABORT:
            self.state = IDLE
            self.window = None
            self._ack(cmd, 0)
        elif cmd == c.STATUS_Q:
            body = c.STATUS_PAYLOAD.pack(self.state, self.preset, ticks_of(now), self.fault_code)
            self._frame(c.STATUS, body)
        else:
            self._ack(cmd & 0xFF, 2)

    # ---- window

    def on_poll(self, now_s: float) -> None:
        # A stalled host process (or a fast virtual clock) can skip more station time between two
        # polls than the 32-bit stamps span; the board never skips: it catches up in steps, so
        # that the driver's sequential unwrapping sees stamps less than a wrap apart (and in order:
        # from the last stamp sent, a heartbeat's or a crossing's).
        t_s = max(self._last_heartbeat_s, self._last_s) if self.state in (COUNTING, CLOSING) else self._last_heartbeat_s
        while now_s - t_s > MAX_STAMP_GAP_S and self.state in (ARMED, COUNTING, CLOSING):
            t_s += MAX_STAMP_GAP_S
            if not self._advance(t_s):
                return
        self._advance(now_s)

    def next_due_s(self, now_s: float) -> float:
        """When the board next has something to say on a sim:// line (drivers.sim_serial)."""
        if self.state not in (ARMED, COUNTING, CLOSING):
            return math.inf
        due_s = now_s + (EDGE_BATCH_S if self.stream_edges or self.state == CLOSING else REPORT_BATCH_S)
        for t_s in (self.window.open_s, self.window.close_s + 2 * SNAP_S):
            if t_s > now_s:
                due_s = min(due_s, t_s)
        return due_s

    def _advance(self, now_s: float) -> bool:
        """Report the window up to now_s; False if crossings wait for the line (nothing later may go out first)."""
        if self.state not in (ARMED, COUNTING, CLOSING):
            return True
        if self.faults.active(Fault.NO_ANSWER):
            self._last_heartbeat_s = now_s
            return True
        w = self.window
        if self.state == ARMED and now_s >= w.open_s:
            self._frame(c.OPEN, c.OPEN_PAYLOAD.pack(ticks_of(w.open_s)))
            self.state = COUNTING
            self._last_s = w.open_s
        if self.state == COUNTING:
            if self.faults.take(Fault.COUNTER_OVERFLOW):
                self.state, self.fault_code = FAULTED, 1
                self._frame(c.FAULT, c.FAULT_PAYLOAD.pack(1, ticks_of(now_s)))
                return True
            t_hi = min(now_s, w.close_s + SNAP_S)
            if t_hi > self._last_s:
                refs = self.world.reference_crossings_s(self._last_s, t_hi)
                if self._last_ref_s is not None:
                    refs = refs[refs > self._last_ref_s + SNAP_S]  # a deferral ends on a crossing already sent
                fit = max(self.tx_room() - EVENT_RESERVE_BYTES, 0) // REF_FRAME_BYTES
                deferred = len(refs) > fit
                if deferred:
                    # The event FIFO holds what the line cannot take yet: the rest follows next poll,
                    # and no later stamp (a heartbeat) before it.
                    if fit == 0:
                        return False
                    refs = refs[:fit]
                    t_hi = float(refs[-1])
                self._refs(refs)
                if self.stream_edges:
                    t, d = self.world.pulse_edges_s(self._last_s, t_hi)
                    # The window's own edges, recomputed, may land a rounding error on either
                    # side of open_s/close_s: count (open_s, close_s] to within half a tick.
                    keep = (t > w.open_s + SNAP_S) & (t <= w.close_s + SNAP_S)
                    self._edges(t[keep], d[keep])
                self._last_s = t_hi
                if deferred:
                    return False
            if self._last_s >= w.close_s:
                self._frame(c.CLOSE, c.CLOSE_PAYLOAD.pack(ticks_of(w.close_s), int(w.pulses)))
                self.state = CLOSING
                if self._closing_crossing_seen() or not self.world.table_moving(w.close_s):
                    self._done()
                    return True
        if self.state == CLOSING:
            if now_s > self._last_s:
                refs = self.world.reference_crossings_s(self._last_s, now_s)
                self._last_s = now_s
                if len(refs):
                    self._refs(refs[:1])
                    self._done()
                    return True
            if now_s > w.close_s + CLOSING_LIMIT_S:
                self._done()
                return True
        if now_s - self._last_heartbeat_s >= c.HEARTBEAT_S:
            self._last_heartbeat_s = now_s
            self._frame(c.HEARTBEAT, c.HEARTBEAT_PAYLOAD.pack(ticks_of(now_s), self.state))
        return True

    def _closing_crossing_seen(self) -> bool:
        return self._last_ref_s is not None and self._last_ref_s >= self.window.close_s

    def _refs(self, times: np.ndarray) -> None:
        for t in np.asarray(times, dtype=float).tolist():
            self._frame(c.REF, c.REF_PAYLOAD.pack(self._n_refs, ticks_of(t)))
            self._n_refs += 1
            self._last_ref_s = t

    def _edges(self, times: np.ndarray, dirs: np.ndarray) -> None:
        n = len(times)
        if n == 0:
            return
        per_frame_bytes = 7 + c.EDGES_HEADER.size + c.MAX_EDGES_PER_FRAME * c.EDGE_DTYPE.itemsize
        room_frames = max(self.tx_room() - 256, 0) // per_frame_bytes  # keep room for events
        fit = min(n, room_frames * c.MAX_EDGES_PER_FRAME)
        edges = np.zeros(fit, dtype=c.EDGE_DTYPE)
        edges["ticks"] = ticks_of_array(times[:fit])
        edges["dir"] = np.asarray(dirs[:fit])
        for i in range(0, fit, c.MAX_EDGES_PER_FRAME):
            chunk = edges[i : i + c.MAX_EDGES_PER_FRAME]
            head = c.EDGES_HEADER.pack(self._edge_index, len(chunk))
            self._frame(c.EDGES, head + chunk.tobytes())
            self._edge_index += len(chunk)
        dropped = n - fit
        self._edge_index += dropped
        self.edges_dropped += dropped

    def _done(self) -> None:
        self._frame(c.DONE, c.DONE_PAYLOAD.pack(self._n_refs, self.edges_dropped))
        self.state = DONE_STATE
        self._last_ref_s = None
