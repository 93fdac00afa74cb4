"""Wire format of the grating read head's interface board: the one codec that its driver and its emulator share.

Frames in the binary framing of `drivers.serial_port`; frame types, payloads and the
BiSS-C single-cycle word as listed in drivers.grating.driver.
"""

from __future__ import annotations

import struct

import numpy as np

from drivers.serial_port import OVERHEAD, SYNC, TICK_S, crc16_rows

DEVICE = "grating read head"

# frame types
START, STOP, STATUS_Q = 0x01, 0x02, 0x03
ACK, STATUS, SAMPLE = 0x81, 0x83, 0x10

BASE_RATE_HZ = 5000.0
TICKS_PER_CYCLE = round(1.0 / BASE_RATE_HZ / TICK_S)  # 4000
POSITION_BITS = 36
NM_PER_COUNT = 1.0

SAMPLE_PAYLOAD = struct.Struct("<HI6s")
ACK_PAYLOAD = struct.Struct("<BB")
STATUS_PAYLOAD = struct.Struct("<BHIB")
START_PAYLOAD = struct.Struct("<H")


# ---------------------------------------------------------------- BiSS word


def _crc6_table() -> list[int]:
    # CRC register left-aligned in 8 bits: polynomial 0x43 -> (0x43 & 0x3F) << 2.
    table = []
    for byte in range(256):
        reg = byte
        for _ in range(8):
            reg = ((reg << 1) ^ 0x0C) & 0xFF if reg & 0x80 else (reg << 1) & 0xFF
        table.append(reg)
    return table


CRC6_TABLE = _crc6_table()
CRC6_TABLE_NP = np.array(CRC6_TABLE, dtype=np.uint8)


def biss_crc6(data_bits: int, n_bits: int = POSITION_BITS + 2) -> int:
    """BiSS CRC-6 (poly 0x43, init 0, inverted) of the `n_bits` bits of data_bits, MSB first."""
    n_bytes = (n_bits + 7) // 8  # leading zero bits leave a zero-init CRC unchanged
    reg = 0
    for byte in data_bits.to_bytes(n_bytes, "big"):
        reg = CRC6_TABLE[reg ^ byte]
    return (~(reg >> 2)) & 0x3F


def biss_word(position: int, n_error: int = 1, n_warning: int = 1) -> int:
    """44-bit BiSS single-cycle word: position, nE, nW, inverted CRC-6."""
    lim = 1 << (POSITION_BITS - 1)
    if not -lim <= position < lim:
        raise ValueError(f"position {position} does not fit {POSITION_BITS} bits")
    data = ((position & ((1 << POSITION_BITS) - 1)) << 2) | (n_error << 1) | n_warning
    return (data << 6) | biss_crc6(data)


def biss_words_np(position: np.ndarray, n_error: np.ndarray, n_warning: np.ndarray) -> np.ndarray:
    """Vectorised biss_word for the emulator (uint64 array)."""
    data = (
        ((position.astype(np.int64) & ((1 << POSITION_BITS) - 1)).astype(np.uint64) << 2)
        | (n_error.astype(np.uint64) << 1)
        | n_warning.astype(np.uint64)
    )
    return (data << np.uint64(6)) | _biss_crc6_np(data).astype(np.uint64)


def _biss_crc6_np(data: np.ndarray) -> np.ndarray:
    """biss_crc6 of every 38-bit data field of a uint64 array (5 bytes, MSB first)."""
    reg = np.zeros(data.shape, dtype=np.uint8)
    for shift in (32, 24, 16, 8, 0):
        reg = CRC6_TABLE_NP[reg ^ ((data >> np.uint64(shift)) & np.uint64(0xFF)).astype(np.uint8)]
    return (~(reg >> 2)) & 0x3F


def decode_biss(word: int) -> tuple[int, bool, bool, bool]:
    """(position, error, warning, crc_ok) of a BiSS word; error/warning are active-high here."""
    data = word >> 6
    crc_ok = biss_crc6(data) == (word & 0x3F)
    pos = data >> 2
    if pos & (1 << (POSITION_BITS - 1)):
        pos -= 1 << POSITION_BITS
    return pos, not (data >> 1) & 1, not data & 1, crc_ok


def decode_biss_np(words: np.ndarray) -> tuple[list[int], list[bool], list[bool], list[bool]]:
    """decode_biss of every word of a uint64 array at once, as Python values (position, error, warning,
    crc_ok), each equal to what decode_biss gives for that word."""
    data = words >> np.uint64(6)
    crc_ok = _biss_crc6_np(data) == (words & np.uint64(0x3F))
    pos = (data >> np.uint64(2)).astype(np.int64)
    pos = np.where(pos & (1 << (POSITION_BITS - 1)), pos - (1 << POSITION_BITS), pos)
    error = ((data >> np.uint64(1)) & np.uint64(1)) == 0
    warning = (data & np.uint64(1)) == 0
    return pos.tolist(), error.tolist(), warning.tolist(), crc_ok.tolist()


# ---------------------------------------------------------------- SAMPLE frames, vectorised

SAMPLE_FRAME_LEN = OVERHEAD + SAMPLE_PAYLOAD.size

# numpy layout of a whole SAMPLE frame, for vectorised encoding
SAMPLE_FRAME_DTYPE = np.dtype(
    [
        ("sync", "u1", 2),
        ("type", "u1"),
        ("len", "<u2"),
        ("seq", "<u2"),
        ("ticks", "<u4"),
        ("biss", "u1", 6),
        ("crc", "<u2"),
    ]
)
assert SAMPLE_FRAME_DTYPE.itemsize == SAMPLE_FRAME_LEN


def encode_sample_frames(seq: np.ndarray, ticks: np.ndarray, words: np.ndarray) -> bytes:
    """Consecutive SAMPLE frames: u16 seq, u32 ticks (both wrapped here), 6-byte BiSS word, CRC-16 each."""
    n = len(seq)
    frames = np.zeros(n, dtype=SAMPLE_FRAME_DTYPE)
    frames["sync"] = np.frombuffer(SYNC, dtype=np.uint8)
    frames["type"] = SAMPLE
    frames["len"] = SAMPLE_PAYLOAD.size
    frames["seq"] = np.asarray(seq) & 0xFFFF
    frames["ticks"] = (np.asarray(ticks) & 0xFFFFFFFF).astype(np.uint32)
    for j in range(6):
        frames["biss"][:, j] = (words >> np.uint64(8 * (5 - j))) & np.uint64(0xFF)
    raw = frames.view(np.uint8).reshape(n, SAMPLE_FRAME_LEN)
    frames["crc"] = crc16_rows(raw[:, 2 : SAMPLE_FRAME_LEN - 2])
    return frames.tobytes()


def sample_fields(payloads: np.ndarray) -> tuple[list[int], list[int], np.ndarray]:
    """(seq16, ticks, BiSS words) of SAMPLE payloads (rows of uint8), as SAMPLE_PAYLOAD.unpack gives them."""
    p = payloads.astype(np.uint64)
    seq16 = p[:, 0] | (p[:, 1] << np.uint64(8))
    ticks = p[:, 2] | (p[:, 3] << np.uint64(8)) | (p[:, 4] << np.uint64(16)) | (p[:, 5] << np.uint64(24))
    words = np.zeros(len(p), dtype=np.uint64)
    for j in range(6):  # big-endian, as int.from_bytes(word_b, "big")
        words = (words << np.uint64(8)) | p[:, 6 + j]
    return seq16.astype(np.int64).tolist(), ticks.astype(np.int64).tolist(), words
