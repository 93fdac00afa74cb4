"""How much a file from outside may make the station read: the limits, their defaults, and the running total.

Sizes are what a file declares (an .npy header's shape x itemsize, an HDF5 dataset's shape x itemsize, each
chunk's size once inflated), checked before the data is read, so that a small file cannot claim gigabytes.
`station import` uses `DEFAULT_LIMITS`; the panel's gap upload passes tighter ones (web.archive).
"""

from __future__ import annotations

from dataclasses import dataclass

from station.errors import InputError

MiB = 1 << 20


@dataclass(frozen=True)
class RawLimits:
    """Bytes one array, and all the arrays of one session directory together, may hold once decompressed."""

    max_array_bytes: int = 512 * MiB  # one dataset or .npy (a long window's raw stream is ~100 MB)
    max_session_bytes: int = 8192 * MiB  # every array of the session's files together


DEFAULT_LIMITS = RawLimits()


class RawInputError(InputError):
    """A file from outside that is not plain data of the expected form: names the file, the dataset and what
    is allowed."""

    def __init__(self, file: str, dataset: str | None, reason: str) -> None:
        where = file if dataset is None else f"{file}, dataset {dataset!r}"
        super().__init__(f"{where}: {reason}")
        self.file, self.dataset, self.reason = file, dataset, reason


class Budget:
    """The bytes a session's arrays may still take; each array's declared size is taken before it is read."""

    def __init__(self, limits: RawLimits = DEFAULT_LIMITS) -> None:
        self.limits = limits
        self.left = limits.max_session_bytes

    def take(self, nbytes: int, file: str, dataset: str | None) -> None:
        lim = self.limits
        if nbytes > lim.max_array_bytes:
            raise RawInputError(file, dataset, f"declares {nbytes} bytes; at most {lim.max_array_bytes} bytes "
                                f"({lim.max_array_bytes / MiB:g} MiB) per array")  # fmt: skip
        if nbytes > self.left:
            raise RawInputError(file, dataset, f"declares {nbytes} bytes, past the session's limit of "
                                f"{lim.max_session_bytes} bytes ({lim.max_session_bytes / MiB:g} MiB) for all "
                                "its arrays together")  # fmt: skip
        self.left -= nbytes
