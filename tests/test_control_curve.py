"""The control channel under CURVE (`station serve` gives its telemetry keys, keys_dir): zmq buffers every frame
of a multipart message before it delivers any (ZMQ_MAXMSGSIZE bounds each frame, nothing bounds their count: 3000
frames of 60 kB from one peer took the server from 98 to 432 MB). Under CURVE only the holders of an allowed key
complete the handshake, so nobody else gets a frame into the server's memory.

Measured: a peer without the keys (NULL mechanism, a DEALER in its own process) sends one message of FRAMES
frames of FRAME_BYTES (180 MB); the server's RSS may grow by at most RSS_GROWTH (allocator noise and zmq's
buffers for a refused handshake), and the panel's client, with the keys, is answered all along. Tolerance on
time: the allowed client's reply within REPLY_S on a loaded 2-core machine.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import psutil
import pytest
import zmq
from control_fuzz import TOKEN, RecordingController

from station.cli.control import ControlServer
from station.control_channel import ControlClient
from station.telemetry import ensure_telemetry_keys

pytestmark = pytest.mark.timeout(120)
FRAMES = 3000
FRAME_BYTES = 60_000
RSS_GROWTH = 40 << 20
REPLY_S = 5.0


@pytest.fixture
def served(tmp_path) -> Iterator[tuple[ControlServer, RecordingController, Path]]:
    keys = ensure_telemetry_keys(tmp_path / "telemetry-keys")
    controller = RecordingController()
    server = ControlServer(controller, "tcp://127.0.0.1:*", token=TOKEN, keys_dir=keys).start()  # type: ignore[arg-type]  # a recording controller
    yield server, controller, keys
    server.close()


def _many_frames(endpoint: str, sent: Any) -> None:
    """One message of FRAMES frames from a DEALER without the keys (in its own process: its memory is its own)."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDTIMEO, 5000)
    sock.connect(endpoint)
    frame = os.urandom(FRAME_BYTES)
    with contextlib.suppress(zmq.Again):
        sock.send_multipart([b"", *([frame] * FRAMES)], copy=False)
    sent.set()
    time.sleep(3.0)  # the connection stays open while the server is measured
    sock.close()
    ctx.term()


def test_a_peer_without_the_keys_gets_no_frame_into_the_server(served) -> None:
    server, _controller, keys = served
    client = ControlClient(server.endpoint, token=TOKEN, timeout_s=REPLY_S, keys_dir=keys)
    assert client.request("status")["ok"] is True  # the panel's keys: answered
    me = psutil.Process()
    rss0 = me.memory_info().rss
    sent = multiprocessing.get_context("spawn").Event()
    peer = multiprocessing.get_context("spawn").Process(target=_many_frames, args=(server.endpoint, sent))
    peer.start()
    try:
        assert sent.wait(30)
        time.sleep(1.0)  # what the server would have read of it by now
        growth = me.memory_info().rss - rss0
        t0 = time.monotonic()
        assert client.request("status")["ok"] is True
        took = time.monotonic() - t0
    finally:
        peer.join(10)
        if peer.is_alive():
            peer.kill()
    print(f"RSS {growth / 2**20:+.1f} MiB after {FRAMES} frames of {FRAME_BYTES} B from a peer without keys; "
          f"the allowed client answered in {took * 1e3:.0f} ms")  # fmt: skip
    assert growth < RSS_GROWTH, f"RSS grew {growth / 2**20:.0f} MiB; allowed {RSS_GROWTH >> 20}"
    assert took < REPLY_S
    client.close()


def test_only_the_allowed_keys_are_answered(served, tmp_path) -> None:
    server, controller, keys = served
    no_keys = ControlClient(server.endpoint, token=TOKEN, timeout_s=1.0)  # the right token, no CURVE
    assert no_keys.request("status")["error"]["type"] == "Timeout"
    other = ensure_telemetry_keys(tmp_path / "other-keys")  # keys of another station: not allowed here
    (other / "station.key").write_bytes((keys / "station.key").read_bytes())  # even with this server's public key
    stranger = ControlClient(server.endpoint, token=TOKEN, timeout_s=1.0, keys_dir=other)
    assert stranger.request("abort")["error"]["type"] == "Timeout"
    assert "abort" not in controller.calls
    allowed = ControlClient(server.endpoint, token=TOKEN, timeout_s=REPLY_S, keys_dir=keys)
    assert allowed.request("abort")["ok"] is True and controller.calls == ["abort"]
    for c in (no_keys, stranger, allowed):
        c.close()
