"""The station's errors: one base class, and the two kinds every error is.

- `InputError`: what was given is not allowed (a file, a field, a value); raised before anything
  moves, and its message names the file or field, the value and what is allowed.
- `StationFault`: something went wrong while the station ran (a device, the store, the timing).

Every error the software raises on purpose derives from `StationError`, so a caller that must
catch them all (the console, the control channel, the panel) catches one class.
"""

from __future__ import annotations


class StationError(Exception):
    """Base of every error the station software raises on purpose."""


class InputError(StationError, ValueError):
    """Bad input: a file, field or value that is not allowed (nothing has moved)."""


class StationFault(StationError, RuntimeError):  # noqa: N818 - a fault, named as the lab does
    """A fault while the station ran: a device, the store, the timing capture, an analysis."""


class DeviceError(StationFault):
    """A device failed or refused a request (drivers.errors has the typed kinds: timeout, frame, fault, ...)."""


class TransientFault(DeviceError):  # noqa: N818 - a fault, named as the lab does
    """A device fault after which the measurement under way can be repeated safely: a damaged frame, a lost
    stretch of a stream; nothing moved wrongly and nothing is left latched (station.engine.runner's repeat policy)."""
