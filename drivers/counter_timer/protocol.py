"""Wire format of the counter/timer board: the one codec that its driver and its emulator share.

Binary framing of `drivers.serial_port` (sync A5 5A, type, u16 length, payload,
CRC-16/CCITT), little-endian, 921600 baud; time stamps are 32-bit counts of
50 ns ticks. The frames and their payloads are listed in drivers.counter_timer.driver.
"""

from __future__ import annotations

import struct

import numpy as np

DEVICE = "counter/timer"

ARM, ABORT, STATUS_Q = 0x20, 0x21, 0x22
ACK, STATUS = 0xA0, 0xA2
OPEN, REF, EDGES, CLOSE, DONE, HEARTBEAT, FAULT = 0xB0, 0xB1, 0xB2, 0xB3, 0xB4, 0xB5, 0xBF

ARM_PAYLOAD = struct.Struct("<iB")
ACK_PAYLOAD = struct.Struct("<BB")
STATUS_PAYLOAD = struct.Struct("<BiIB")
OPEN_PAYLOAD = struct.Struct("<I")
REF_PAYLOAD = struct.Struct("<II")
EDGES_HEADER = struct.Struct("<IH")
EDGE_DTYPE = np.dtype([("ticks", "<u4"), ("dir", "i1")])
CLOSE_PAYLOAD = struct.Struct("<Ii")
DONE_PAYLOAD = struct.Struct("<II")
HEARTBEAT_PAYLOAD = struct.Struct("<IB")
FAULT_PAYLOAD = struct.Struct("<BI")

FLAG_STREAM_EDGES = 0x01
MAX_PRESET = 2**31 - 1
MAX_EDGES_PER_FRAME = 400
HEARTBEAT_S = 1.0
STATES = {0: "idle", 1: "armed", 2: "counting", 3: "closing", 4: "done", 5: "fault"}
FAULTS = {1: "counter overflow"}
ACK_RESULTS = {1: "busy (a window is under way)", 2: "bad argument"}
IDLE, ARMED, COUNTING, CLOSING, DONE_STATE, FAULTED = range(6)  # the STATUS / HEARTBEAT state byte
