"""The indexing head as a device of every station: its [indexing_head] section, how it opens and how it is emulated."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers.config import IndexingHeadSection
from drivers.indexing_head.driver import IndexingHead
from drivers.registry import DeviceKind
from station.clock import Clock


def open_indexing_head(
    section: IndexingHeadSection, clock: Clock, *, motion_permitted: Callable[[], bool] | None = None
) -> IndexingHead:
    """The head, settling as the section says; `motion_permitted`: the station's interlock (table at rest)."""
    return IndexingHead(section.port or "", baud=section.baud, settle_tol_deg=section.settle_tol_deg,
                        settle_time_s=section.settle_time_s, clock=clock,
                        motion_permitted=motion_permitted).open()  # fmt: skip


def emulate_indexing_head(section: IndexingHeadSection, world: Any) -> Any:
    """The head's controller on the world (whose head turns at the section's speed_deg_s); started."""
    from drivers.indexing_head.emulator import IndexingEmulator

    emulator = IndexingEmulator(world, baud=section.baud)
    return world.attach(emulator)


DEVICE_KIND = DeviceKind("indexing_head", IndexingHeadSection, open_indexing_head, emulate_indexing_head, core=True)
