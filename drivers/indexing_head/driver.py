"""Indexing head (rotary stage) speaking a Zaber-style ASCII protocol.

Command  `/<device> <axis> <id> <command> [<data>]:<lrc>\\n`
Reply    `@<device:02d> <axis> <id> <flag> <status> <warning> <data>:<lrc>\\r\\n`

- id: message id 0..99, echoed in the reply (stale replies are discarded);
- flag: OK or RJ (rejected; data is the reason: BADCOMMAND, BADDATA, ...);
- status: BUSY (moving) or IDLE;
- warning: the most important active warning flag or `--`: WR no reference
  position (not homed since power-up), NI command interrupted (stopped while
  moving), FS stalled;
- lrc: sum of the bytes between the leading `/` or `@` and the `:`, mod 256,
  two's complement, two upper-case hex digits.

Commands: `` (status only), `home`, `move abs <counts>`, `stop`, `get pos`
(data: position in counts), `warnings` (data: `NN F1 F2 ...`),
`warnings clear`. Positions are encoder counts, `counts_per_deg` per degree
(default 10000, i.e. 0.0001 deg); the head's own angle error lives in the
twin, the driver reports the encoder angle. Lines starting with `#` (info)
or `!` (alert) are ignored.

Errors: no reply -> DeviceTimeout; malformed or truncated reply -> FrameError;
bad lrc -> ChecksumError; RJ -> DeviceFault (field "reply"); target outside
[min_deg, max_deg] -> LimitError (nothing sent); a move while held or while
`motion_permitted()` is false -> InterlockError (nothing sent); port gone ->
Disconnected. Queries (status, position, warnings) and stop are retried;
moves and home are not (a move that timed out may have started).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from dataclasses import dataclass

from drivers.errors import (
    DeviceFault,
    DeviceTimeout,
    DriverError,
    FrameError,
    InterlockError,
    LimitError,
)
from drivers.indexing_head.protocol import DEVICE, Reply, decode_reply, encode_command
from drivers.serial_port import SerialDevice, with_retries
from station.clock import Clock, WallClock

# ---------------------------------------------------------------- driver


@dataclass(frozen=True)
class HeadStatus:
    busy: bool
    warnings: tuple[str, ...]
    position_deg: float


class IndexingHead(SerialDevice):
    """Driver of the indexing head.

    Safety hooks for the interlock layer: `motion_permitted()` is checked
    before every move or home (False -> InterlockError, nothing sent);
    `hold()` stops the head and refuses moves until `release()`.
    Settling is judged on `clock` (station time): position within
    `settle_tol_deg` of the target, head idle, for `settle_time_s`.
    """

    DEVICE = DEVICE

    def __init__(
        self,
        port: str,
        *,
        baud: int = 115_200,
        device: int = 1,
        axis: int = 1,
        counts_per_deg: float = 10_000.0,
        min_deg: float = -720.0,
        max_deg: float = 720.0,
        timeout_s: float = 0.5,
        retries: int = 2,
        settle_tol_deg: float = 0.001,
        settle_time_s: float = 0.5,
        poll_s: float = 0.05,
        move_timeout_s: float = 120.0,
        motion_permitted: Callable[[], bool] | None = None,
        clock: Clock | None = None,
    ) -> None:
        if not min_deg < max_deg:
            raise ValueError(f"min_deg {min_deg} must be < max_deg {max_deg}")
        super().__init__(port, baud, clock=clock)
        self.device = device
        self.axis = axis
        self.counts_per_deg = counts_per_deg
        self.min_deg = min_deg
        self.max_deg = max_deg
        self.timeout_s = timeout_s
        self.retries = retries
        self.settle_tol_deg = settle_tol_deg
        self.settle_time_s = settle_time_s
        self.poll_s = poll_s
        self.move_timeout_s = move_timeout_s
        self.motion_permitted = motion_permitted
        self.clock: Clock = clock if clock is not None else WallClock()
        self._msg_id = 0
        self._held = threading.Event()

    # ---- transactions

    def _transact(self, command: str) -> Reply:
        """One command and its reply (matched by device, axis and message id)."""
        lines = self.lines
        with self._io:
            self._msg_id = (self._msg_id + 1) % 100
            mid = self._msg_id
            lines.link.write(encode_command(self.device, self.axis, mid, command))
            deadline_s = self._link_clock.now_s() + self.timeout_s
            while True:
                left_s = deadline_s - self._link_clock.now_s()
                if left_s <= 0:
                    raise DeviceTimeout(DEVICE, f"no reply to {command or 'status'!r}")
                try:
                    line = lines.read_line(left_s)
                except DeviceTimeout:
                    raise DeviceTimeout(
                        DEVICE, f"no reply to {command or 'status'!r} within {self.timeout_s:g} s"
                    ) from None
                if line[:1] in (b"#", b"!") or not line:
                    continue
                reply = decode_reply(line)
                if (reply.device, reply.axis, reply.msg_id) != (self.device, self.axis, mid):
                    continue  # a stale reply to an earlier attempt
                if not reply.ok:
                    raise DeviceFault(
                        DEVICE,
                        f"{command!r} rejected: {reply.data}",
                        field="reply",
                        value=reply.data,
                    )
                return reply

    def _query(self, command: str) -> Reply:
        def flush() -> None:
            if self._lines is not None:
                self._lines.clear()

        return with_retries(lambda: self._transact(command), self.retries, before_retry=flush)

    # ---- queries

    def position_deg(self) -> float:
        """Encoder angle (query, retried)."""
        return self._pos_of(self._query("get pos"))

    def _pos_of(self, reply: Reply) -> float:
        try:
            return int(reply.data) / self.counts_per_deg
        except ValueError as exc:
            raise FrameError(DEVICE, f"position {reply.data!r} is not an integer") from exc

    def status(self) -> HeadStatus:
        """Busy flag, all active warning flags and the encoder angle (queries, retried)."""
        w = self._query("warnings")
        tokens = w.data.split()
        try:
            n = int(tokens[0])
        except (IndexError, ValueError) as exc:
            raise FrameError(DEVICE, f"malformed warnings {w.data!r}") from exc
        flags = tuple(tokens[1 : 1 + n])
        p = self._query("get pos")
        return HeadStatus(p.busy, flags, self._pos_of(p))

    def clear_warnings(self) -> tuple[str, ...]:
        """Clear the clearable warnings (NI, ...); returns those that were active."""
        tokens = self._query("warnings clear").data.split()
        return tuple(tokens[1:])

    # ---- motion

    @property
    def held(self) -> bool:
        return self._held.is_set()

    def _check_motion_allowed(self, what: str) -> None:
        if self._held.is_set():
            raise InterlockError(DEVICE, f"{what} refused: head is held (release() first)")
        if self.motion_permitted is not None and not self.motion_permitted():
            raise InterlockError(DEVICE, f"{what} refused: motion not permitted by the interlock")

    def move_abs(self, target_deg: float) -> None:
        """Start a move to target_deg (not retried; see the module docstring)."""
        if not self.min_deg <= target_deg <= self.max_deg:
            raise LimitError(
                DEVICE,
                "target out of range",
                field="target_deg",
                value=target_deg,
                allowed=f"{self.min_deg} .. {self.max_deg} deg",
            )
        self._check_motion_allowed(f"move to {target_deg} deg")
        counts = round(target_deg * self.counts_per_deg)
        try:
            self._transact(f"move abs {counts}")
        except DeviceTimeout as exc:
            raise DeviceTimeout(
                DEVICE,
                f"move to {target_deg} deg not acknowledged: the head may be moving; query status() or stop()",
            ) from exc

    def home(self) -> None:
        """Start homing (not retried)."""
        self._check_motion_allowed("home")
        self._transact("home")

    def stop(self) -> None:
        """Decelerate to a stop (idempotent, retried)."""
        self._query("stop")

    def hold(self) -> None:
        """Refuse moves until release(), and stop the head (raises if the stop fails)."""
        self._held.set()
        self.stop()

    def release(self) -> None:
        self._held.clear()

    def wait_settled(
        self,
        target_deg: float,
        *,
        tol_deg: float | None = None,
        settle_s: float | None = None,
        timeout_s: float | None = None,
    ) -> float:
        """Poll until idle within tol_deg of target_deg for settle_s (station time); the angle.

        Raises DeviceTimeout after timeout_s (station time), InterlockError if
        the head is held meanwhile.
        """
        tol = self.settle_tol_deg if tol_deg is None else tol_deg
        settle = self.settle_time_s if settle_s is None else settle_s
        limit = self.move_timeout_s if timeout_s is None else timeout_s
        t0 = self.clock.now_s()
        since: float | None = None
        while True:
            if self._held.is_set():
                raise InterlockError(DEVICE, f"wait for {target_deg} deg interrupted: head held")
            asked_s = self.clock.now_s()
            reply = self._query("get pos")
            pos = self._pos_of(reply)
            now = self.clock.now_s()
            if not reply.busy and abs(pos - target_deg) <= tol:
                if since is None:
                    since = now
                if now - since >= settle:
                    return pos
            else:
                since = None
            # Only a head seen away from the target (or busy) by a query sent after the deadline times out:
            # with a stalled host on a fast virtual clock a reading from before the stall arrives after it.
            if asked_s - t0 > limit and since is None:
                raise DeviceTimeout(
                    DEVICE,
                    f"not settled at {target_deg} deg within {limit:g} s "
                    f"(at {pos:.4f} deg, {'busy' if reply.busy else 'idle'})",
                )
            self.clock.sleep_s(self.poll_s)

    def move_to(self, target_deg: float, **settle: float) -> float:
        """move_abs then wait_settled; returns the settled encoder angle."""
        self.move_abs(target_deg)
        try:
            return self.wait_settled(target_deg, **settle)
        except DeviceTimeout:
            with contextlib.suppress(DriverError):
                self.stop()
            raise
