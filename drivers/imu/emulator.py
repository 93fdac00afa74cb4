"""Emulator of the strapdown IMU (protocol in drivers.imu.protocol), on the fixture on the shaker's slip table.

Samples are made on the exact grid of station time (t_k = k / rate, stamps multiples of the
period in 50 ns ticks) from the twin (`station.twin.strapdown_imu`): the table's motion is the
world's shared `ShakerMotion` (what the shaker controller's emulator drives), seen through the
fixture's rubber dampers, in the pose the simulated operator mounted (`{"fixture_pose": k}`,
station.twin.fixture_poses; each mounting has its own small pose error). Increments are
quantised to the LSBs of the INFO reply with the remainder carried, as a real IMU's counters do.

Pacing: each poll makes the samples whose time has come on world.clock. What does not fit the
transmit FIFO is dropped with its seq counted (a visible gap), as an IMU whose FIFO overflows
would (a pty line at a virtual clock faster than the line carries; a sim:// line carries its
baud in station time). Samples that would not fit (a reader that stopped) are dropped without
being made.

Faults: NO_ANSWER (commands ignored, `count` of them; the stream goes silent while armed),
GARBLE / TRUNCATE / CRC_ERROR (the next frame), DISCONNECT; device-specific `sensor_fault(bits)`
(status bits on every sample until cleared with `sensor_fault(0)`) and `drop(n)` (the next n
samples lost).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from drivers.errors import DriverError
from drivers.imu import protocol as imu
from drivers.pty_link import Fault, PtyEmulator, garble, truncate
from drivers.serial_port import TICK_S, FrameParser, encode_frame
from station.twin.fixture_poses import POSES, ROCKING_AXIS_N, SLIP_AXIS_N, mounted
from station.twin.shaker_motion import ShakerMotion
from station.twin.strapdown_imu import Site, StrapdownImuTwin, fixture_motion, nodes_for, sensor_errors, true_increments

GYRO_LSB_RAD = 1e-9
ACCEL_LSB_MPS = 1e-7
# The interface's buffer: some 25 s of wall time at the capped speed. Generous, because what stalls
# here is the simulation's host (a loaded machine starves reader and emulator alike while the
# virtual clock runs on), not the IMU.
FIFO_BYTES = 1 << 22
SERIAL = b"SINS-RLG-0002"


_BENCH = ShakerMotion()  # where the IMU lies before it is mounted: a table that never moves


def _bad_crc(frame: bytes) -> bytes:
    return frame[:-1] + bytes([frame[-1] ^ 0x5A])


class ImuEmulator(PtyEmulator):
    name = "imu-emulator"
    supported_faults = frozenset({Fault.NO_ANSWER, Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.DISCONNECT})

    def __init__(self, world: Any, *, baud: int = 3_000_000, fifo_bytes: int = FIFO_BYTES, **kw: Any) -> None:
        super().__init__(world.clock, baud=baud, fifo_bytes=fifo_bytes, **kw)
        self.world = world
        self.twin: StrapdownImuTwin = world.shared("strapdown_imu", StrapdownImuTwin)
        self.motion: ShakerMotion = world.shared("shaker", ShakerMotion)
        st = world.twin.station
        self.site = Site(st.g_mps2, st.earth_rate_radps, st.latitude_rad)
        self.rng = np.random.default_rng(int(world.rng.integers(2**63)))
        self._rx = FrameParser("imu host")
        self.rate_hz = 200
        self.streaming = False
        self.pose: int | None = None  # None: lying level on the bench, off the shaker
        self._c_bn = np.eye(3)
        self._next_k = 0
        self._seq = 0
        self._theta_rad = 0.0  # the rocking angle at the next sample's start edge
        self._carry = np.zeros(6)  # quantisation remainders, in LSB
        self.status_bits = 0
        self._drop = 0
        self.dropped = 0
        self._queued = 0  # bytes ever queued; with len(_tx), how many went out
        self._frame_starts: deque[int] = deque()
        world.on_operator("fixture_pose", self._mount)

    # ---- the operator

    def _mount(self, value: Any, t_s: float) -> None:
        if value not in POSES:
            raise DriverError("simulated operator", "no such fixture pose", field="fixture_pose", value=value,
                              allowed=", ".join(map(str, POSES)))  # fmt: skip
        if self.motion.moving(t_s):
            raise DriverError("simulated operator", "cannot remount the IMU while the shaker runs")
        self._c_bn = mounted(POSES[value], self.rng.normal(0.0, self.twin.mount_error_rad, 3))
        self.pose = value

    # ---- device-specific faults

    def sensor_fault(self, bits: int) -> None:
        self.status_bits = bits

    def drop(self, n: int) -> None:
        self._drop += n

    # ---- commands

    def on_bytes(self, data: bytes) -> None:
        self._rx.feed(data)
        while (item := self._rx.next_item()) is not None:
            if isinstance(item, Exception) or self.faults.take(Fault.NO_ANSWER):
                continue
            self._command(item.type, item.payload)

    def _reply(self, frame_type: int, payload: bytes) -> None:
        self.send(self._damaged(encode_frame(frame_type, payload)))

    def _ack(self, cmd: int, result: int) -> None:
        self._reply(imu.ACK, imu.ACK_PAYLOAD.pack(cmd, result))

    def _command(self, cmd: int, payload: bytes) -> None:
        now = self.clock.now_s()
        if cmd == imu.START:
            self._discard_queued()
            self._ack(cmd, 0)
            if not self.streaming:
                self._next_k = math.floor(now * self.rate_hz) + 1
                self._seq = 0
                self._theta_rad = self._angle_at(self._next_k - 1)
                self.streaming = True
        elif cmd == imu.STOP:
            self.streaming = False
            self._discard_queued()
            self._ack(cmd, 0)
        elif cmd == imu.INFO_Q:
            body = imu.INFO_PAYLOAD.pack(self.rate_hz, GYRO_LSB_RAD, ACCEL_LSB_MPS, int(self.streaming), SERIAL)
            self._reply(imu.INFO, body)
        elif cmd == imu.RATE and len(payload) == imu.RATE_PAYLOAD.size:
            (rate,) = imu.RATE_PAYLOAD.unpack(payload)
            if self.streaming:
                self._ack(cmd, 2)
            elif rate not in imu.RATES_HZ:
                self._ack(cmd, 1)
            else:
                self.rate_hz = rate
                self._ack(cmd, 0)
        else:
            self._ack(cmd & 0xFF, 1)

    def send(self, data: bytes, frames: int = 1) -> None:
        """Queue `frames` frames of equal length, keeping where each starts (see _discard_queued)."""
        self._forget_sent()
        before = len(self._tx)
        super().send(data)
        if len(self._tx) > before:
            self._frame_starts.extend(self._queued + len(data) // frames * np.arange(frames))
            self._queued += len(data)

    def _forget_sent(self) -> int:
        """Bytes gone out so far; the starts of frames wholly gone are forgotten."""
        sent = self._queued - len(self._tx)
        starts = self._frame_starts
        while len(starts) > 1 and starts[1] <= sent:
            starts.popleft()
        return sent

    def _discard_queued(self) -> None:
        """Drop the queued frames but the one on the wire, which finishes (a cut frame would hide the reply)."""
        sent = self._forget_sent()
        starts = self._frame_starts
        keep = 0
        if starts and starts[0] < sent:  # that frame is under way: its rest goes out
            keep = (starts[1] if len(starts) > 1 else self._queued) - sent
        del self._tx[keep:]
        self._queued = sent + keep
        starts.clear()
        if keep:
            starts.append(sent)

    def _damaged(self, frame: bytes) -> bytes:
        for fault, damage in ((Fault.GARBLE, garble), (Fault.TRUNCATE, truncate), (Fault.CRC_ERROR, _bad_crc)):
            if self.faults.take(fault):
                return damage(frame)
        return frame

    # ---- stream

    @property
    def _table(self) -> ShakerMotion:
        """What the IMU stands on: the shaker once mounted, the bench before."""
        return self.motion if self.pose is not None else _BENCH

    def _angle_at(self, k: int) -> float:
        """The rocking angle at grid edge k (to restart the telescoping sum after a gap)."""
        ((theta, _),) = self._table.response(
            np.array([k / self.rate_hz]), np.zeros(1), (self.twin.dampers.rocking_gain,)
        )
        return float(theta[0, 0])

    def on_poll(self, now_s: float) -> None:
        if not self.streaming:
            return
        n_due = math.floor(now_s * self.rate_hz) - self._next_k + 1
        if n_due <= 0:
            return
        silent = self.faults.active(Fault.NO_ANSWER)
        forced = min(self._drop, n_due)
        self._drop -= forced
        room = 0 if silent else max(self.tx_room() // imu.SAMPLE_FRAME_BYTES - 1, 0)
        send = min(n_due - forced, room)
        skip = n_due - send  # the oldest due samples, never made: seq counts them
        if skip:
            self._next_k += skip
            self._seq += skip
            self.dropped += 0 if silent else skip
            self._theta_rad = self._angle_at(self._next_k - 1)
        if send:
            self.send(self._encode(send), send)

    def next_due_s(self, now_s: float) -> float:
        """When the stream next has a batch for a sim:// line (drivers.sim_serial); idle, nothing is due."""
        if not self.streaming:
            return math.inf
        return self.stream_due_s(self._next_k / self.rate_hz, now_s)

    def _increments(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The next n samples' increments in LSB counts (twin, sensor errors, quantisation)."""
        dt = 1.0 / self.rate_hz
        edges = (self._next_k - 1 + np.arange(n + 1)) * dt
        twin = self.twin
        k = nodes_for(self.motion.max_freq_hz(), dt)
        motion = fixture_motion(self._table.response, edges, self._theta_rad, twin.dampers, k)
        self._theta_rad = motion.theta_end_rad
        d_theta, d_v = true_increments(edges, motion, self._c_bn, SLIP_AXIS_N, ROCKING_AXIS_N, np.asarray(twin.tau),
                                       self.site)  # fmt: skip
        e_theta, e_v = sensor_errors(n, dt, twin, self.rng)
        lsb = np.hstack([(d_theta + e_theta) / GYRO_LSB_RAD, (d_v + e_v) / ACCEL_LSB_MPS])
        total = np.cumsum(lsb, axis=0) + self._carry
        counts = np.diff(np.floor(total + 0.5), axis=0, prepend=np.zeros((1, 6)))
        self._carry = total[-1] - np.floor(total[-1] + 0.5)
        return counts[:, :3].astype(np.int64), counts[:, 3:].astype(np.int64)

    def _encode(self, n: int) -> bytes:
        d_theta, d_v = self._increments(n)
        k = self._next_k + np.arange(n, dtype=np.int64)
        ticks = k * round(1.0 / (self.rate_hz * TICK_S))
        out = imu.encode_sample_frames(self._seq + np.arange(n), ticks, d_theta, d_v, self.status_bits)
        self._next_k += n
        self._seq += n
        size = imu.SAMPLE_FRAME_DTYPE.itemsize
        return self._damaged(out[:size]) + out[size:]
