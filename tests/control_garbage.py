"""What an attacker or a broken peer sends to the control channel: garbage floods, for the tests and bench/.

`flood` runs in its own process (`flooding`), so that the garbage competes with the station for the CPU as
another program would, not for the station's GIL.
"""

from __future__ import annotations

import multiprocessing
import os
import random
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from multiprocessing.synchronize import Event as MpEvent

import zmq

KINDS = ("tcp", "envelope", "bare", "replay")


def flood(endpoint: str, kinds: tuple[str, ...], stop: MpEvent, seed: int, replay: list[bytes] | None = None) -> None:
    """Send garbage of the given kinds, round robin, until stop is set:

    tcp       64 kB of random bytes on a new TCP connection (not even a ZMTP greeting)
    envelope  REQ-shaped four frames (empty delimiter first) with random bytes and a wrong MAC, up to 60 kB
    bare      random multipart messages without a REQ envelope, from a DEALER
    replay    `replay` (a captured authentic request) sent again and again
    """
    rng = random.Random(seed)
    host, port = endpoint.removeprefix("tcp://").rsplit(":", 1)
    ctx = zmq.Context()
    dealer = ctx.socket(zmq.DEALER)
    for opt, value in ((zmq.LINGER, 0), (zmq.SNDHWM, 64), (zmq.SNDTIMEO, 0)):
        dealer.setsockopt(opt, value)
    dealer.connect(endpoint)
    try:
        while not stop.is_set():
            for kind in kinds:
                try:
                    if kind == "tcp":
                        with socket.create_connection((host, int(port)), timeout=1.0) as s:
                            s.sendall(os.urandom(65536))
                    elif kind == "envelope":
                        n = rng.choice((16, 1024, 60_000))
                        dealer.send_multipart([b"", b"panel", os.urandom(64), os.urandom(24), os.urandom(n)])
                    elif kind == "bare":
                        dealer.send_multipart([os.urandom(rng.randrange(1, 2048)) for _ in range(rng.randrange(1, 6))])
                    elif kind == "replay" and replay:
                        dealer.send_multipart([b"", *replay])
                except (zmq.Again, OSError):  # the station's queue for this peer is full, or the port refused
                    pass
    finally:
        dealer.close()
        ctx.term()


@contextmanager
def flooding(endpoint: str, kinds: tuple[str, ...] = KINDS, seed: int = 0, replay: list[bytes] | None = None,
             processes: int = 1) -> Iterator[None]:  # fmt: skip
    """`processes` flood processes for the block."""
    stop = multiprocessing.Event()
    procs = [
        multiprocessing.Process(target=flood, args=(endpoint, kinds, stop, seed + i, replay), daemon=True)
        for i in range(processes)
    ]
    for p in procs:
        p.start()
    try:
        yield
    finally:
        stop.set()
        for p in procs:
            p.join()
