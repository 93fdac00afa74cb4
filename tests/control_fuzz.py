"""Control-channel frames for fuzzing (tests/test_fuzz_control.py, bench/fuzz_control.py): a station controller
that only records what it is asked, and a probe that sends one message and reads what comes back."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import zmq
from hypothesis import strategies as st

from station.cli.control import ControlServer
from station.clock import utc_s
from station.control_channel import MAX_REQUEST_BYTES, ControlError, Stamp, request_frames
from station.engine.runner import StopCount

TOKEN = "fuzz-token-" + "f" * 32
CMDS = (
    "library",
    "plan",
    "start",
    "resume_session",
    "pause",
    "resume",
    "abort",
    "estop",
    "acknowledge",
    "reset",
    "warp",
    "",
    None,
    7,
)  # fmt: skip (never "status": the probe's own request)
ACTIONS = ("status", "library", "plan", "start", "resume_session", "pause", "resume", "abort", "acknowledge", "reset",
           "emergency_stop")  # fmt: skip


@dataclass
class RecordingController:
    """What ControlServer calls on a StationController, each call recorded by name; nothing moves."""

    calls: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        me = self

        class Engine:
            operator: str | None = None

            class progress:  # noqa: N801 - the attribute path the server reads
                session_uid = None

            def acknowledge(self) -> None:
                me.calls.append("acknowledge")

            def stop_count(self) -> StopCount:
                return StopCount(0, me.calls.count("emergency_stop"))

        self.engine = Engine()

    def __getattr__(self, name: str) -> Any:
        if name not in ACTIONS:
            raise AttributeError(name)

        def action(*args: Any, **kwargs: Any) -> Any:
            self.calls.append(name)
            if name in ("plan", "start", "resume_session"):
                raise ControlError(f"{name}: the recording controller plans nothing")
            return {"state": "idle"} if name == "status" else None

        return action


class Probe:
    """A DEALER that speaks to the server as a REQ would, and as anything else would."""

    def __init__(self, server: ControlServer) -> None:
        self.sock = zmq.Context.instance().socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(server.endpoint)
        self._seq = 0

    def signed(self, body: bytes, *, sender: bytes = b"fuzzprob", t_s: float | None = None) -> list[bytes]:
        self._seq += 1
        return request_frames(TOKEN, b"panel", Stamp(sender, self._seq, utc_s() if t_s is None else t_s), body)

    def exchange(self, frames: list[bytes], envelope: bool, timeout_ms: int = 5000) -> list[dict] | None:
        """Send `frames` (after an empty delimiter if envelope), then a valid status request; every reply that came
        before the status reply, parsed; None if the status reply did not come within timeout_ms."""
        self.sock.send_multipart([b"", *frames] if envelope else frames)
        self.sock.send_multipart([b"", *self.signed(json.dumps({"cmd": "status"}).encode())])
        before: list[dict] = []
        while True:
            if not self.sock.poll(timeout_ms):
                return None
            reply = json.loads(self.sock.recv_multipart()[-1])
            if reply.get("result") == {"state": "idle"}:
                return before
            before.append(reply)

    def close(self) -> None:
        self.sock.close()


blob = st.binary(max_size=2048)
json_body = st.fixed_dictionaries(
    {"cmd": st.sampled_from(CMDS)},
    optional={"args": st.one_of(st.dictionaries(st.text(max_size=8), st.integers() | st.text(max_size=8), max_size=3),
                                st.lists(st.integers(), max_size=3), st.none(), st.integers()),
              "user": st.text(max_size=80) | st.integers()},
).map(lambda d: json.dumps(d).encode())  # fmt: skip


CAPTURED = ("start", "pause", "estop")
UNAUTHENTICATED = ("random", "flip", "truncate", "extra", "replay", "identity", "stamp")


@st.composite
def unauthenticated(draw: st.DrawFn, captured: list[bytes], kind: str) -> list[bytes]:
    """Frames that must never reach the controller: random, or the captured request broken or sent again."""
    if kind == "random":
        return draw(st.lists(blob, min_size=1, max_size=6))
    frames = list(captured)
    if kind == "flip":  # one byte of one frame changed
        i = draw(st.integers(0, 3))
        if not frames[i]:
            return [*frames[:i], b"x", *frames[i + 1 :]]
        j = draw(st.integers(0, len(frames[i]) - 1))
        bit = draw(st.integers(1, 255))
        frames[i] = frames[i][:j] + bytes([frames[i][j] ^ bit]) + frames[i][j + 1 :]
    elif kind == "truncate":
        frames = frames[: draw(st.integers(1, 3))]
    elif kind == "extra":
        frames.insert(draw(st.integers(0, 4)), draw(blob))
    elif kind == "identity":
        frames[0] = draw(st.sampled_from((b"", b"mallory", b"panel\0", b"PANEL", b"cli")))
    elif kind == "stamp":
        frames[2] = draw(st.binary(max_size=40).filter(lambda b: b != captured[2]))
    return frames  # "replay": as captured


WRONG = ("lost", "reply count", "unauthenticated action", "accepted", "internal error", "dead thread")


@dataclass
class Rig:
    """A server over a recording controller, a probe, and one captured request (a pause, done once)."""

    server: ControlServer
    controller: RecordingController
    probe: Probe
    captured: dict[str, list[bytes]] = field(default_factory=dict)
    captured_at_s: float = 0.0
    counts: Counter[str] = field(default_factory=Counter)

    @classmethod
    def start(cls) -> Rig:
        controller = RecordingController()
        server = ControlServer(controller, "tcp://127.0.0.1:*", token=TOKEN).start()  # type: ignore[arg-type]
        rig = cls(server, controller, Probe(server))
        rig.capture()
        return rig

    def capture(self) -> None:
        """A start, a pause and an emergency stop, each done once: replayed and broken by the fuzz while fresh (new
        ones every 20 s)."""
        self.captured_at_s = utc_s()
        for cmd in CAPTURED:
            self.captured[cmd] = self.probe.signed(json.dumps({"cmd": cmd, "args": {"procedure": "p"}}).encode())
            first = self.probe.exchange(self.captured[cmd], envelope=True)
            assert first is not None and len(first) == 1 and "UnknownCommand" not in str(first), first

    def close(self) -> None:
        self.probe.close()
        self.server.close()

    def fuzz_one(self, draw: st.DrawFn) -> list[str]:
        """One drawn message and a valid request after it; what went wrong (empty if nothing), counted by kind in
        self.counts: lost (the valid request unanswered), unauthenticated action, accepted (an ok reply to an
        unauthenticated frame), internal error, wrong reply count, dead thread."""
        if utc_s() - self.captured_at_s > 20.0:
            self.capture()
        n_calls = len(self.controller.calls)
        which = draw(st.sampled_from(("unauthenticated", "stale", "authentic")))
        if which == "unauthenticated":
            kind = draw(st.sampled_from(UNAUTHENTICATED))
            self.counts[kind] += 1
            frames = draw(unauthenticated(self.captured[draw(st.sampled_from(CAPTURED))], kind))
        elif which == "stale":
            offset_s = draw(st.floats(31, 1e9) | st.floats(-1e9, -31))
            frames = self.probe.signed(draw(json_body), t_s=max(utc_s() + offset_s, 0.0))
        else:  # a token holder's odd requests: well-formed answers, whatever the body
            frames = self.probe.signed(draw(json_body | blob | st.just(b"[" * (MAX_REQUEST_BYTES - 100))))
        envelope = draw(st.booleans())
        replies = self.probe.exchange(frames, envelope)
        sent = [b"", *frames] if envelope else frames
        answered = len(sent) >= 2 and sent[0] == b""  # what the server can tell from a REQ's envelope
        wrong: list[str] = []
        if replies is None:
            wrong.append("lost")
            replies = []
        elif len(replies) != int(answered):
            wrong.append("reply count")
        if which != "authentic":
            if any(call != "status" for call in self.controller.calls[n_calls:]):  # the probe's own request only
                wrong.append("unauthenticated action")
            if any(r["ok"] for r in replies):
                wrong.append("accepted")
        if any(not r["ok"] and r["error"]["type"] == "InternalError" for r in replies):
            wrong.append("internal error")
        if not (self.server._thread.is_alive() and self.server._worker.is_alive()):
            wrong.append("dead thread")
        self.counts[which] += 1
        self.counts.update(wrong)
        return wrong
