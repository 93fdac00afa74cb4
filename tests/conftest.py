"""Fixtures shared across the suite: the links a device test runs on (tests/links.py)."""

from __future__ import annotations

import pytest
from links import CAN_INTERFACES, TRANSPORTS


@pytest.fixture(params=TRANSPORTS)
def transport(request: pytest.FixtureRequest) -> str:
    """The serial link between driver and emulator: a pty or a sim:// line."""
    return str(request.param)


@pytest.fixture(params=CAN_INTERFACES)
def interface(request: pytest.FixtureRequest) -> str:
    """The python-can interface of the servo's bus: `virtual` or `station_sim`."""
    return str(request.param)
