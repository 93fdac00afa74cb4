"""Indexing head: Zaber-style codec, then the real driver against its emulator over a pty and a sim:// line,
the head's motion coming from the world (speed from the world's configuration).
"""

from __future__ import annotations

import threading
import time

import pytest

from drivers.errors import (
    ChecksumError,
    DeviceFault,
    DeviceTimeout,
    Disconnected,
    FrameError,
    InterlockError,
    LimitError,
)
from drivers.indexing_head import protocol as ih
from drivers.pty_link import Fault

pytestmark = pytest.mark.timeout(60)


# ---------------------------------------------------------------- codec


def test_lrc_makes_the_byte_sum_zero() -> None:
    for body in (b"1 1 12 move abs 12800", b"01 1 12 OK BUSY -- 0", b""):
        assert (sum(body) + ih.lrc(body)) % 256 == 0
    assert ih.encode_message("/", "1 1 get pos") == b"/1 1 get pos:%02X" % ih.lrc(b"1 1 get pos")


def test_reply_roundtrip_with_and_without_message_id() -> None:
    line = ih.encode_message("@", "01 1 07 OK BUSY WR 12800")
    assert ih.decode_reply(line) == ih.Reply(1, 1, 7, True, True, "WR", "12800")
    line = ih.encode_message("@", "01 1 RJ IDLE -- BADDATA")
    assert ih.decode_reply(line) == ih.Reply(1, 1, None, False, False, "--", "BADDATA")
    line = ih.encode_message("@", "01 1 03 OK IDLE NI 02 NI WR")
    assert ih.decode_reply(line).data == "02 NI WR"


def test_bad_replies_raise_typed_errors() -> None:
    line = ih.encode_message("@", "01 1 07 OK BUSY -- 0")
    with pytest.raises(ChecksumError):
        ih.decode_reply(line[:-2] + b"%02X" % ((int(line[-2:], 16) + 1) % 256))
    for bad in (line[: len(line) // 2], b"#01 1 info", ih.encode_message("@", "01 1 07 OK")):
        with pytest.raises(FrameError):
            ih.decode_reply(bad)


# ---------------------------------------------------------------- driver against emulator


def test_status_home_and_move(index_rig) -> None:
    world, emu, head = index_rig
    st = head.status()
    assert not st.busy and "WR" in st.warnings  # not homed since power-up
    head.home()
    assert head.wait_settled(0.0) == pytest.approx(0.0, abs=1e-4)
    assert "WR" not in head.status().warnings
    head.move_abs(30.0)
    assert head.status().busy
    angle = head.wait_settled(30.0)
    assert angle == pytest.approx(30.0, abs=head.settle_tol_deg)
    now = world.clock.now_s()
    assert angle == pytest.approx(world.index_position_deg(now), abs=1e-4)  # encoder counts
    assert not world.index_busy(now)
    assert "move abs 300000" in emu.commands


def test_move_to_settles_for_the_settle_time(index_rig) -> None:
    world, _, head = index_rig
    t0 = world.clock.now_s()
    head.move_to(-20.0, settle_s=0.5)
    assert world.clock.now_s() - t0 >= 0.5
    assert head.position_deg() == pytest.approx(-20.0, abs=1e-4)


def test_limits_are_checked_before_sending(index_rig) -> None:
    _, emu, head = index_rig
    n = len(emu.commands)
    with pytest.raises(LimitError, match="target_deg"):
        head.move_abs(head.max_deg + 1)
    assert len(emu.commands) == n


def test_device_rejection_is_a_device_fault(index_rig) -> None:
    _, _, head = index_rig
    with pytest.raises(DeviceFault, match="BADCOMMAND"):
        head._transact("fly")


def test_interlock_guard_and_hold(index_rig) -> None:
    _, emu, head = index_rig
    permitted = threading.Event()
    head.motion_permitted = permitted.is_set
    n = len(emu.commands)
    with pytest.raises(InterlockError, match="not permitted"):
        head.move_abs(10.0)
    with pytest.raises(InterlockError):
        head.home()
    assert len(emu.commands) == n  # nothing sent
    permitted.set()
    head.move_abs(90.0)
    head.hold()  # stops the head and refuses moves
    assert emu.commands[-1] == "stop"
    with pytest.raises(InterlockError, match="held"):
        head.move_abs(0.0)
    with pytest.raises(InterlockError, match="held"):
        head.wait_settled(90.0)
    assert "NI" in head.status().warnings  # the move was interrupted
    head.release()
    head.move_to(0.0)


def test_hold_from_another_thread_interrupts_a_wait(index_rig) -> None:
    _, _, head = index_rig
    head.move_abs(200.0)
    timer = threading.Timer(0.2, head.hold)
    timer.start()
    with pytest.raises(InterlockError):
        head.wait_settled(200.0, timeout_s=60.0)
    timer.join()
    assert not head.status().busy


@pytest.mark.parametrize("fault", [Fault.GARBLE, Fault.TRUNCATE, Fault.CRC_ERROR, Fault.NO_ANSWER])
def test_queries_survive_one_bad_reply(index_rig, fault) -> None:
    _, emu, head = index_rig
    emu.inject(fault)
    assert head.position_deg() == pytest.approx(0.0, abs=1e-4)


@pytest.mark.parametrize(
    ("fault", "error"),
    [
        (Fault.GARBLE, FrameError),
        (Fault.TRUNCATE, FrameError),
        (Fault.CRC_ERROR, ChecksumError),
        (Fault.NO_ANSWER, DeviceTimeout),
    ],
)
def test_persistent_bad_replies_give_typed_errors(index_rig, fault, error) -> None:
    _, emu, head = index_rig
    emu.inject(fault, count=None)
    t0 = time.monotonic()
    with pytest.raises(error, match="after 3 attempts"):
        head.position_deg()
    assert time.monotonic() - t0 < 3 * head.timeout_s + 0.5


def test_moves_are_not_retried(index_rig) -> None:
    _, emu, head = index_rig
    emu.inject(Fault.NO_ANSWER, count=1)
    n = len(emu.commands)
    with pytest.raises(DeviceTimeout, match="may be moving"):
        head.move_abs(45.0)
    time.sleep(0.05)
    head.position_deg()
    assert emu.commands[n:].count("move abs 450000") == 0  # dropped, never repeated
    emu.inject(Fault.CRC_ERROR, count=1)
    with pytest.raises(ChecksumError):
        head.move_abs(45.0)
    assert emu.commands[n:].count("move abs 450000") == 1


def test_disconnect(index_rig) -> None:
    _, emu, head = index_rig
    head.position_deg()
    emu.disconnect()
    with pytest.raises(Disconnected):
        for _ in range(50):
            head.position_deg()
            time.sleep(0.01)
    head.close()
