"""Wire format of the precision voltmeter (SCPI over RS-232): the one codec that its driver and its emulator share.

The commands, ranges and reply format as listed in drivers.voltmeter.driver: LF-terminated
lines, readings in NR3 (`+1.23456789E+00`) separated by commas, +9.9E37 on overload.
"""

from __future__ import annotations

import re

import numpy as np

from drivers.errors import FrameError

DEVICE = "voltmeter"
RANGES_V = (0.2, 2.0, 20.0, 200.0, 1000.0)
OVERRANGE = 1.05
NPLC_LIMITS = (0.01, 50.0)
MAX_SAMPLES = 1024
OVERLOAD_V = 9.9e37
CONVERSIONS_PER_READING = 2  # auto-zero: signal and reference
NR3 = re.compile(rb"[+-]\d\.\d+E[+-]\d{2}")


def reading_s(nplc: float, samples: int, line_hz: float) -> float:
    """Station time one READ? takes."""
    return samples * CONVERSIONS_PER_READING * nplc / line_hz


def parse_readings(line: bytes, samples: int) -> np.ndarray:
    """`samples` NR3 readings in volts; FrameError if the line is anything else."""
    fields = line.split(b",")
    if len(fields) != samples or not all(NR3.fullmatch(f) for f in fields):
        raise FrameError(DEVICE, f"expected {samples} NR3 readings, got {line[:80]!r}")
    return np.array([float(f) for f in fields])


# SCPI long forms to the short forms the instrument matches on.
SHORT = {"CONFIGURE": "CONF", "VOLTAGE": "VOLT", "SENSE": "SENS", "RANGE": "RANG", "NPLCYCLES": "NPLC",
         "SAMPLE": "SAMP", "COUNT": "COUN", "SYSTEM": "SYST", "ERROR": "ERR"}  # fmt: skip


def command_path(command: str) -> tuple[str, str]:
    """(short-form header path without the optional SENS node, argument) of one SCPI command."""
    header, _, arg = command.partition(" ")
    nodes = [SHORT.get(n, n) for n in header.upper().lstrip(":").split(":")]
    if nodes[0] == "SENS":
        nodes = nodes[1:]
    return ":".join(nodes), arg


def format_readings(volts: np.ndarray) -> str:
    """A READ? reply line (without LF): NR3 readings with 9 significant digits, comma-separated."""
    return ",".join(f"{v:+.8E}" for v in volts)
