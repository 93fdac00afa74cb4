"""CANopen timing on python-can's virtual bus: the servo driver against its emulator.

Measures
- SDO round trip: VibrationTableServo.read_error_code() (one expedited upload of 0x603F);
- TPDO latency: from the emulator's send (the virtual bus stamps each frame) to a canopen
  subscriber callback on a third Bus, the path the driver's TPDO handling takes;
- TPDO period: intervals between TPDO2 frames (event timer 10 ms in the EDS);
- enable(): the three confirmed 402 transitions;
- per transport (python-can's `virtual` bus with canopen's Notifier thread, against `station_sim`, which delivers
  in the sender's thread): CPU (process time, every thread) and wall per CAN frame (send, then wait until the
  receiving Notifier's listener has it) and per SDO round trip (expedited upload from a canopen RemoteNode to a
  LocalNode, nothing else on the bus).
Prints markdown tables. Usage: .venv/bin/python bench/bench_can.py [--n-sdo 2000] [--n-tpdo 500] [--n-frames 20000]

Simulation path: the servo driver against its emulator on the CAN interfaces, without the engine (no session).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import canopen
import numpy as np

from drivers.config import load_station_config
from drivers.servo.driver import ServoLimits, VibrationTableServo
from drivers.servo.emulator import ServoEmulator
from station.clock import WallClock

CONFIG = Path(__file__).parents[1] / "config" / "stations/vibration-sim.toml"
EDS = Path(__file__).parents[1] / "config" / "eds" / "vibration_table_servo.eds"
TRANSPORTS = ("virtual", "station_sim")


def _ms(values_s: list[float]) -> tuple[float, float]:
    a = np.asarray(values_s) * 1e3
    return float(np.median(a)), float(np.percentile(a, 99))


def _tpdo_timing(channel: str, cob_id: int, n: int) -> tuple[list[float], list[float]]:
    """(latencies, periods) of n TPDOs seen by a canopen subscriber on its own Bus."""
    latencies_s: list[float] = []
    stamps_s: list[float] = []
    done = threading.Event()

    def on_tpdo(can_id: int, data: bytearray, timestamp: float) -> None:
        latencies_s.append(time.time() - timestamp)
        stamps_s.append(timestamp)
        if len(stamps_s) > n:
            done.set()

    network = canopen.Network(can.Bus(interface="virtual", channel=channel))
    network.NOTIFIER_CYCLE = 0.05
    network.subscribe(cob_id, on_tpdo)
    network.connect()
    try:
        if not done.wait(timeout=0.02 * n + 5):
            raise SystemExit(f"only {len(stamps_s)} of {n} TPDOs received")
    finally:
        network.disconnect()
    return latencies_s[1:], list(np.diff(stamps_s))


def _per_item_us(n: int, run: Callable[[], None]) -> tuple[float, float]:
    """(CPU, wall) in microseconds per item of run(), which handles n items."""
    cpu0, wall0 = time.process_time(), time.perf_counter()
    run()
    return (time.process_time() - cpu0) / n * 1e6, (time.perf_counter() - wall0) / n * 1e6


def _frame_cost_us(interface: str, n: int) -> tuple[float, float]:
    """Send a frame and wait until the receiver's Notifier listener has it, n times."""
    channel = f"bench-frame-{os.getpid()}-{interface}"
    got = threading.Event()
    with can.Bus(interface=interface, channel=channel) as tx, can.Bus(interface=interface, channel=channel) as rx:
        msg = can.Message(arbitration_id=0x185, data=bytes(8), is_extended_id=False)
        with can.Notifier(rx, [lambda _msg: got.set()], timeout=0.05):

            def run() -> None:
                for _ in range(n):
                    got.clear()
                    tx.send(msg)
                    if not got.wait(5.0):
                        raise SystemExit(f"{interface}: a frame was not delivered within 5 s")

            return _per_item_us(n, run)


def _sdo_cost_us(interface: str, n: int) -> tuple[float, float]:
    """n expedited SDO uploads (0x1017) from a RemoteNode to a LocalNode."""
    channel = f"bench-sdo-{os.getpid()}-{interface}"
    drive, master = canopen.Network(), canopen.Network()
    for network in (drive, master):
        network.NOTIFIER_CYCLE = 0.05
        network.connect(interface=interface, channel=channel)
    try:
        drive.create_node(5, str(EDS))
        remote = master.add_node(5, str(EDS))

        def run() -> None:
            for _ in range(n):
                remote.sdo.upload(0x1017, 0)

        return _per_item_us(n, run)
    finally:
        master.disconnect()
        drive.disconnect()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-sdo", type=int, default=2000, help="SDO round trips")
    parser.add_argument("--n-tpdo", type=int, default=500, help="TPDOs (10 ms each)")
    parser.add_argument("--n-frames", type=int, default=20000, help="frames per transport")
    args = parser.parse_args()

    cfg = load_station_config(CONFIG)
    servo_cfg = dataclasses.replace(cfg.servo, channel=f"bench-can-{os.getpid()}")
    clock = WallClock()
    with (
        ServoEmulator.from_config(servo_cfg, clock) as _emu,
        VibrationTableServo(servo_cfg, ServoLimits.from_config(cfg), clock) as servo,
    ):
        enable_s = []
        for _ in range(20):
            t0 = time.perf_counter()
            servo.enable()
            enable_s.append(time.perf_counter() - t0)
            servo.disable()
        sdo_s = []
        for _ in range(args.n_sdo):
            t0 = time.perf_counter()
            servo.read_error_code()
            sdo_s.append(time.perf_counter() - t0)
        latency_s, period_s = _tpdo_timing(servo_cfg.channel, 0x280 + servo_cfg.node_id, args.n_tpdo)

    rows = [
        ("SDO round trip (upload 0x603F)", len(sdo_s), *_ms(sdo_s)),
        ("TPDO latency (send -> canopen callback)", len(latency_s), *_ms(latency_s)),
        ("TPDO2 period (event timer 10 ms)", len(period_s), *_ms(period_s)),
        ("enable(): 3 confirmed 402 transitions", len(enable_s), *_ms(enable_s)),
    ]
    print(
        f"python-can {can.__version__}, canopen {canopen.__version__}, "
        f"Python {platform.python_version()}, {platform.machine()}, virtual bus\n"
    )
    print("| measurement | n | median (ms) | p99 (ms) |")
    print("|---|---:|---:|---:|")
    for name, n, median_ms, p99_ms in rows:
        print(f"| {name} | {n} | {median_ms:.3f} | {p99_ms:.3f} |")

    print("\n| transport | frame CPU (us) | frame wall (us) | SDO round trip CPU (us) | SDO round trip wall (us) |")
    print("|---|---:|---:|---:|---:|")
    for interface in TRANSPORTS:
        frame_cpu_us, frame_wall_us = _frame_cost_us(interface, args.n_frames)
        sdo_cpu_us, sdo_wall_us = _sdo_cost_us(interface, args.n_sdo)
        print(f"| {interface} | {frame_cpu_us:.1f} | {frame_wall_us:.1f} | {sdo_cpu_us:.1f} | {sdo_wall_us:.1f} |")


if __name__ == "__main__":
    main()
