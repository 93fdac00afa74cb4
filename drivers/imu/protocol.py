"""Wire format of the strapdown IMU: the one codec that its driver and its emulator share.

Frames in the binary framing of `drivers.serial_port`; frame types and payloads as listed in
drivers.imu.driver.
"""

from __future__ import annotations

import struct

import numpy as np

from drivers.serial_port import OVERHEAD, SYNC, crc16

DEVICE = "strapdown IMU"

START, STOP, INFO_Q, RATE = 0x40, 0x41, 0x42, 0x43
ACK, INFO, SAMPLE = 0xC0, 0xC2, 0x50
RATES_HZ = (200, 400, 500, 1000)
ACK_PAYLOAD = struct.Struct("<BB")
RATE_PAYLOAD = struct.Struct("<H")
INFO_PAYLOAD = struct.Struct("<HddB16s")
SAMPLE_DTYPE = np.dtype([("seq", "<u4"), ("ticks", "<u4"), ("dtheta", "<i4", 3), ("dv", "<i4", 3), ("status", "u1")])
SAMPLE_FRAME_BYTES = OVERHEAD + SAMPLE_DTYPE.itemsize
STATUS_BITS = {0: "gyro fault", 1: "accelerometer fault or saturation", 2: "over-temperature"}
ACK_RESULTS = {1: "bad argument", 2: "busy: streaming"}

# a whole SAMPLE frame, for vectorised encoding
SAMPLE_FRAME_DTYPE = np.dtype([("sync", "u1", 2), ("type", "u1"), ("len", "<u2"), ("body", SAMPLE_DTYPE),
                               ("crc", "<u2")])  # fmt: skip


def encode_sample_frames(seq: np.ndarray, ticks: np.ndarray, dtheta: np.ndarray, dv: np.ndarray,
                         status: int) -> bytes:  # fmt: skip
    """Consecutive SAMPLE frames: u32 seq and ticks (wrapped here), increments in LSB counts (n, 3), status."""
    n = len(seq)
    frames = np.zeros(n, dtype=SAMPLE_FRAME_DTYPE)
    frames["sync"] = np.frombuffer(SYNC, dtype=np.uint8)
    frames["type"] = SAMPLE
    frames["len"] = SAMPLE_DTYPE.itemsize
    body = frames["body"]
    body["seq"] = np.asarray(seq) & 0xFFFFFFFF
    body["ticks"] = np.asarray(ticks) & 0xFFFFFFFF
    body["dtheta"] = dtheta
    body["dv"] = dv
    body["status"] = status
    raw = frames.view(np.uint8).reshape(n, SAMPLE_FRAME_DTYPE.itemsize)
    frames["crc"] = [crc16(row[2:-2].tobytes()) for row in raw]
    return frames.tobytes()
