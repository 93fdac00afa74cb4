"""Indexing head: known-answer lines from the Zaber-style protocol in drivers.indexing_head.driver's docstring.

Command `/<device> <axis> <id> <command> [<data>]:<lrc>` LF; reply `@<device:02d> <axis> <id> <flag> <status>
<warning> <data>:<lrc>` CR LF; lrc the two's complement of the byte sum between the lead and the `:`, mod 256,
as two upper-case hex digits (worked out by hand for each line below). Positions in counts, 10 000 per degree.
"""

from __future__ import annotations

import pytest
from wire import FrozenClock, answers, scripted_port

from drivers.errors import ChecksumError, DeviceFault, LimitError
from drivers.indexing_head.driver import IndexingHead
from drivers.indexing_head.emulator import IndexingEmulator
from drivers.world import SimStation


def _head(port: str) -> IndexingHead:
    return IndexingHead(port, timeout_s=0.3, retries=2, clock=FrozenClock())


def test_position_query() -> None:
    with (
        scripted_port([(b"/1 1 1 get pos:5B\n", b"@01 1 01 OK IDLE -- 123456:06\r\n")]) as port,
        _head(port).open() as h,
    ):
        assert h.position_deg() == pytest.approx(12.3456, abs=1e-9)


def test_move_abs_in_counts() -> None:
    with (
        scripted_port([(b"/1 1 1 move abs 900000:B7\n", b"@01 1 01 OK BUSY -- 0:E6\r\n")]) as port,
        _head(port).open() as h,
    ):
        h.move_abs(90.0)


def test_a_rejected_move_is_a_device_fault() -> None:
    transcript = [(b"/1 1 1 move abs 900000:B7\n", b"@01 1 01 RJ IDLE -- BADDATA:58\r\n")]
    with scripted_port(transcript) as port, _head(port).open() as h, pytest.raises(DeviceFault) as info:
        h.move_abs(90.0)
    assert (info.value.field, info.value.value) == ("reply", "BADDATA")


def test_a_target_outside_the_range_sends_nothing() -> None:
    with scripted_port([]) as port, _head(port).open() as h, pytest.raises(LimitError):
        h.move_abs(1000.0)


def test_status_lists_every_warning() -> None:
    transcript = [
        (b"/1 1 1 warnings:A4\n", b"@01 1 01 OK IDLE WR 02 NI WR:0A\r\n"),
        (b"/1 1 2 get pos:5A\n", b"@01 1 02 OK IDLE WR -50000:C9\r\n"),
    ]
    with scripted_port(transcript) as port, _head(port).open() as h:
        status = h.status()
    assert (status.busy, status.warnings, status.position_deg) == (False, ("NI", "WR"), pytest.approx(-5.0))


def test_a_reply_with_a_bad_lrc_is_a_checksum_error_and_the_query_is_asked_again() -> None:
    transcript = [
        (b"/1 1 1 get pos:5B\n", b"@01 1 01 OK IDLE -- 123456:07\r\n"),
        (b"/1 1 2 get pos:5A\n", b"@01 1 02 OK IDLE WR -50000:C9\r\n"),
    ]
    with scripted_port(transcript) as port, _head(port).open() as h:
        assert h.position_deg() == pytest.approx(-5.0)
    with (
        scripted_port([(b"/1 1 1 get pos:5B\n", b"@01 1 01 OK IDLE -- 123456:07\r\n")]) as port,
        IndexingHead(port, timeout_s=0.3, retries=0).open() as h,
        pytest.raises(ChecksumError),
    ):
        h.position_deg()


def test_a_stale_reply_to_an_earlier_attempt_is_skipped_by_its_message_id() -> None:
    transcript = [
        (b"/1 1 1 get pos:5B\n", b""),  # no answer in time: asked again with id 2
        (b"/1 1 2 get pos:5A\n", b"@01 1 01 OK IDLE -- 9:02\r\n@01 1 02 OK IDLE WR -50000:C9\r\n"),
    ]
    with scripted_port(transcript) as port, _head(port).open() as h:
        assert h.position_deg() == pytest.approx(-5.0)


def test_stop() -> None:
    with scripted_port([(b"/1 1 1 stop:47\n", b"@01 1 01 OK IDLE NI 0:CE\r\n")]) as port, _head(port).open() as h:
        h.stop()


# ---------------------------------------------------------------- emulator


@pytest.fixture
def emulator() -> IndexingEmulator:
    return IndexingEmulator(SimStation(clock=FrozenClock()))  # not homed: WR until `home`


def test_emulator_replies(emulator: IndexingEmulator) -> None:
    assert answers(emulator, b"/1 1 5 get pos:57\n") == b"@01 1 05 OK IDLE WR 0:B8\r\n"
    assert answers(emulator, b"/1 1 6 move abs 7200001:81\n") == b"@01 1 06 RJ IDLE WR BADDATA:04\r\n"
    assert answers(emulator, b"/1 1 7 frobnicate:EA\n") == b"@01 1 07 RJ IDLE WR BADCOMMAND:1E\r\n"
    assert answers(emulator, b"/1 1 8 home:5D\n") == b"@01 1 08 OK IDLE -- 0:04\r\n"
    assert answers(emulator, b"/1 1 9 warnings:9C\n") == b"@01 1 09 OK IDLE -- 00:D3\r\n"


def test_emulator_drops_a_bad_lrc_and_other_devices_commands(emulator: IndexingEmulator) -> None:
    assert answers(emulator, b"/1 1 5 get pos:58\n") == b""
    assert answers(emulator, b"/2 1 9 get pos:52\n") == b""
    assert emulator.commands == []
