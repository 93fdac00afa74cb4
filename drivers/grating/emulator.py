"""Emulator of the absolute grating read head's interface board (protocol in drivers.grating.driver and .protocol).

Samples are taken on the exact 5 kHz grid of station time (t_k = k / 5000 s,
time stamps multiples of 4000 ticks), positions from world.table_position_m.
Each poll emits every sample whose time has come on world.clock; if the
transmit FIFO has no room (virtual clock faster than the line, or a driver
that stopped reading), the oldest due samples are dropped and seq still
counts them, so the driver sees the gap. A rate divider (START argument)
lets a fast virtual session ask for fewer samples instead.

Faults: NO_ANSWER (commands ignored and stream silent while armed; count =
commands to ignore), GARBLE / TRUNCATE / CRC_ERROR (applied to the next
frame), SIGNAL_LOSS (nE = 0 on the next `count` samples, or until cleared),
DISCONNECT.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drivers.grating import protocol as g
from drivers.grating.protocol import SAMPLE_FRAME_LEN, encode_sample_frames
from drivers.pty_link import LINK_FAULTS, Fault, PtyEmulator, garble, truncate
from drivers.serial_port import FrameParser, encode_frame, ticks_of

MAX_SAMPLES_PER_POLL = 4000


class GratingEmulator(PtyEmulator):
    name = "grating-emulator"
    supported_faults = LINK_FAULTS | {Fault.SIGNAL_LOSS}

    def __init__(self, world: Any, *, baud: int = 3_000_000, **kw: Any) -> None:
        super().__init__(world.clock, baud=baud, **kw)
        self.world = world
        self._rx = FrameParser("grating host")
        self.streaming = False
        self.divider = 1
        self._next_k = 0  # index of the next sample on the 5 kHz / divider grid
        self._seq = 0
        self.dropped = 0  # samples dropped for lack of FIFO room
        self.sent = 0

    # ---- commands

    def on_bytes(self, data: bytes) -> None:
        self._rx.feed(data)
        while (item := self._rx.next_item()) is not None:
            if isinstance(item, Exception):
                continue
            if self.faults.take(Fault.NO_ANSWER):
                continue
            self._command(item.type, item.payload)

    def _reply(self, frame: bytes) -> None:
        self.send(self._maybe_corrupt(frame))

    def _command(self, cmd: int, payload: bytes) -> None:
        now = self.clock.now_s()
        if cmd == g.START and len(payload) == g.START_PAYLOAD.size:
            (divider,) = g.START_PAYLOAD.unpack(payload)
            if divider < 1:
                self._reply(encode_frame(g.ACK, g.ACK_PAYLOAD.pack(cmd, 1)))
                return
            self.divider = divider
            self._tx.clear()  # a restart flushes whatever was still queued
            self._reply(encode_frame(g.ACK, g.ACK_PAYLOAD.pack(cmd, 0)))
            self._next_k = math.floor(now / self._period_s) + 1
            self._seq = 0
            self.streaming = True
        elif cmd == g.STOP:
            self.streaming = False
            self._reply(encode_frame(g.ACK, g.ACK_PAYLOAD.pack(cmd, 0)))
        elif cmd == g.STATUS_Q:
            flags = (0 if self.faults.active(Fault.SIGNAL_LOSS) else 1) | 2
            body = g.STATUS_PAYLOAD.pack(int(self.streaming), self.divider, ticks_of(now), flags)
            self._reply(encode_frame(g.STATUS, body))
        else:
            self._reply(encode_frame(g.ACK, g.ACK_PAYLOAD.pack(cmd & 0xFF, 1)))

    @property
    def _period_s(self) -> float:
        return self.divider / g.BASE_RATE_HZ

    # ---- stream

    def on_poll(self, now_s: float) -> None:
        if not self.streaming:
            return
        last_k = math.floor(now_s / self._period_s)
        n_due = last_k - self._next_k + 1
        if n_due <= 0:
            return
        if self.faults.active(Fault.NO_ANSWER):  # the board went silent: nothing goes out
            self._skip(n_due, count_as_dropped=False)
            return
        room = min(self.tx_room() // SAMPLE_FRAME_LEN - 1, MAX_SAMPLES_PER_POLL)
        if n_due > room:
            self._skip(n_due - max(room, 0), count_as_dropped=True)
            n_due = max(room, 0)
        if n_due > 0:
            self.send(self._encode(n_due))

    def next_due_s(self, now_s: float) -> float:
        """When the stream next has a batch for a sim:// line (drivers.sim_serial); idle, nothing is due."""
        if not self.streaming:
            return math.inf
        return self.stream_due_s(self._next_k * self._period_s, now_s)

    def _skip(self, n: int, *, count_as_dropped: bool) -> None:
        self._next_k += n
        self._seq = (self._seq + n) & 0xFFFF
        if count_as_dropped:
            self.dropped += n

    def _encode(self, n: int) -> bytes:
        k = np.arange(self._next_k, self._next_k + n, dtype=np.int64)
        t_s = k * self._period_s
        z_m = np.asarray(self.world.table_position_m(t_s), dtype=float)
        n_err = np.ones(n, dtype=np.uint8)
        for i in range(n):
            if not self.faults.take(Fault.SIGNAL_LOSS):
                break
            n_err[i] = 0
        pos = np.where(n_err == 1, np.rint(z_m * 1e9 / g.NM_PER_COUNT), 0).astype(np.int64)
        words = g.biss_words_np(pos, n_err, np.ones(n, dtype=np.uint8))
        out = encode_sample_frames(self._seq + np.arange(n), k * (g.TICKS_PER_CYCLE * self.divider), words)
        self._next_k += n
        self._seq = (self._seq + n) & 0xFFFF
        self.sent += n
        first = self._maybe_corrupt(out[:SAMPLE_FRAME_LEN])
        return first + out[SAMPLE_FRAME_LEN:]

    def _maybe_corrupt(self, frame: bytes) -> bytes:
        if self.faults.take(Fault.GARBLE):
            return garble(frame)
        if self.faults.take(Fault.TRUNCATE):
            return truncate(frame)
        if self.faults.take(Fault.CRC_ERROR):
            b = bytearray(frame)
            b[-1] ^= 0x5A
            return bytes(b)
        return frame
