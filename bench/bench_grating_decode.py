"""CPU per grating SAMPLE frame, parsed one by one (FrameParser.next_item, SAMPLE_PAYLOAD.unpack, decode_biss)
against in bulk (FrameParser.peek_run, sample_fields, decode_biss_np), for frames arriving in batches of B,
and the emulator's vectorised encoding.

    .venv/bin/python bench/bench_grating_decode.py [--frames 20000]

Simulation path: none (the grating's frame decoding and the emulator's encoding, no session).
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable

import numpy as np

from drivers.grating import protocol as g
from drivers.serial_port import FrameParser


def one_by_one(parser: FrameParser) -> None:
    while (item := parser.next_item()) is not None:
        _, _, word_b = g.SAMPLE_PAYLOAD.unpack(item.payload)
        g.decode_biss(int.from_bytes(word_b, "big"))


def in_bulk(parser: FrameParser) -> None:
    run = parser.peek_run(g.SAMPLE, g.SAMPLE_PAYLOAD.size, max_frames=1 << 30)
    seq16, ticks, words = g.sample_fields(run)
    for _ in zip(seq16, ticks, *g.decode_biss_np(words), strict=True):
        pass
    parser.consume_run(len(run), g.SAMPLE_PAYLOAD.size)


def us_per_frame(stream: bytes, n: int, batch: int, parse: Callable[[FrameParser], None]) -> float:
    parser = FrameParser("bench")
    cpu_s = time.process_time()
    for k in range(0, n, batch):
        parser.feed(stream[k * g.SAMPLE_FRAME_LEN : (k + batch) * g.SAMPLE_FRAME_LEN])
        parse(parser)
    return (time.process_time() - cpu_s) / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000)
    n = ap.parse_args().frames
    rng = np.random.default_rng(0)
    words = g.biss_words_np(rng.integers(-(2**30), 2**30, n), np.ones(n, int), np.ones(n, int))
    cpu_s = time.process_time()
    stream = g.encode_sample_frames(np.arange(n), np.arange(n) * g.TICKS_PER_CYCLE, words)
    encode_us = (time.process_time() - cpu_s) / n * 1e6
    print(f"{platform.machine()}, CPython {platform.python_version()}; {n} frames")
    print("\n| frames per batch | one by one (us/frame) | in bulk (us/frame) |\n|---:|---:|---:|")
    for batch in (5, 20, 40, 100, 1000):
        print(f"| {batch} | {us_per_frame(stream, n, batch, one_by_one):.2f} | "
              f"{us_per_frame(stream, n, batch, in_bulk):.2f} |")  # fmt: skip
    print(f"\nencode_sample_frames, {n} at once: {encode_us:.2f} us/frame")


if __name__ == "__main__":
    main()
