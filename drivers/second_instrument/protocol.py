"""The second instrument's counter channel speaks the counter/timer board's wire format: drivers.counter_timer.protocol
(the same board, the same codec)."""

from __future__ import annotations

from drivers.counter_timer.protocol import *  # noqa: F403
