"""The telemetry relay: bounded per-browser queues, seq accounting, fan-out from several stations' PUB sockets."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from station.clock import WallClock
from station.telemetry import TelemetryPublisher
from web.config import StationEntry
from web.relay import BrowserQueue, StationFeed, TelemetryRelay

N = 300  # messages per station


def entry(name: str, telemetry: str = "tcp://127.0.0.1:1") -> StationEntry:
    return StationEntry(name=name, control="tcp://127.0.0.1:1", telemetry=telemetry, store=Path("x.sqlite"),
                        reports=Path("."))  # fmt: skip


def doc(seq: int, topic: str = "status", station: str = "a", data: dict | None = None) -> bytes:
    return json.dumps({"station": station, "topic": topic, "seq": seq, "t_s": 0.0, "wall_s": 0.0,
                       "data": data or {}}).encode()  # fmt: skip


def test_a_full_queue_drops_its_oldest_and_counts():
    async def run():
        queue = BrowserQueue(maxsize=4)
        for i in range(10):
            queue.offer(str(i))
        return queue.dropped, await queue.batch(limit=64)

    assert asyncio.run(run()) == (6, ["6", "7", "8", "9"])


def test_a_feed_counts_lost_messages_restarts_and_malformed_ones():
    feed = StationFeed(entry("a"))
    for seq in (0, 1, 2, 5, 6):  # 3 and 4 lost
        assert feed.accept(doc(seq)) is not None
    feed.accept(doc(0))  # the station started again
    assert feed.accept(b"{not json") is None
    assert feed.accept(doc(1, station="b")) is None
    assert feed.accept(json.dumps({"station": "a"}).encode()) is None
    s = feed.stats()
    assert (s["received"], s["lost"], s["restarts"], s["malformed"], s["last_seq"]) == (6, 2, 1, 3, 0)


def test_a_feed_replays_the_session_history_then_the_latest_of_each_lasting_topic():
    feed = StationFeed(entry("a"))
    for seq, topic in enumerate(["state", "status", "trace", "event", "status", "fault", "progress"]):
        feed.accept(doc(seq, topic))
    replay = [json.loads(t) for t in feed.replay()]
    topics_seqs = [(d["topic"], d["seq"]) for d in replay]
    assert topics_seqs == [("history", None), ("state", 0), ("status", 4), ("progress", 6)]
    history = replay[0]["data"]
    assert [d["seq"] for d in history["notices"]] == [3, 5] and [d["seq"] for d in history["traces"]] == [2]


def test_a_new_session_drops_the_last_sessions_window_point_and_results_from_the_replay():
    """A browser that joins once a new session has started is not shown the last one's open window, point or
    analysis (window and point messages name no session: only the change of session can clear them)."""

    feed = StationFeed(entry("a"))
    first = [("state", {"state": "running", "session_uid": "s1"}), ("window", {"key": "P1", "event": "close"}),
             ("point", {"key": "P1"}), ("analysis", {"session_uid": "s1", "summary": "", "results": {}})]  # fmt: skip
    for seq, (topic, data) in enumerate(first):
        feed.accept(doc(seq, topic, data=data))
    assert {json.loads(t)["topic"] for t in feed.replay()[1:]} == {"state", "window", "point", "analysis"}
    feed.accept(doc(4, "state", data={"state": "running", "session_uid": "s2"}))
    replay = [json.loads(t) for t in feed.replay()]
    assert [(d["topic"], d["data"].get("session_uid")) for d in replay] == [("history", "s2"), ("state", "s2")]
    assert not replay[0]["data"]["closes"] and not replay[0]["data"]["points"]


async def drain(queue: BrowserQueue, traces: int) -> list[dict]:
    """Everything the queue gets until `traces` trace messages came (5 s at most between batches)."""
    out: list[dict] = []
    while sum(d["topic"] == "trace" for d in out) < traces:
        out += [json.loads(t) for t in await asyncio.wait_for(queue.batch(64), 5.0)]
    return out


def test_fan_out_from_two_stations_and_a_slow_browser_loses_only_its_own_backlog():
    pubs = {n: TelemetryPublisher("tcp://127.0.0.1:*", n, WallClock()) for n in ("a", "b")}
    relay = TelemetryRelay([entry(n, p.endpoint) for n, p in pubs.items()], queue_size=2 * N + 50)

    async def run():
        relay.start()
        try:
            # zmq's slow joiner: publish until both SUBs hear, then start counting.
            while any(f.received == 0 for f in relay.feeds.values()):
                for p in pubs.values():
                    p.publish("hello", {})
                await asyncio.sleep(0.01)
            everyone, only_a = relay.subscribe(), relay.subscribe(["a"])
            slow = relay.subscribe(queue_size=8)  # a browser that never reads: its queue stays full
            for i in range(N):
                for p in pubs.values():
                    p.publish("trace", {"i": i})
            got = {"everyone": await drain(everyone, 2 * N), "only_a": await drain(only_a, N)}
            return got, slow
        finally:
            await relay.stop()
            for p in pubs.values():
                p.close()

    got, slow = asyncio.run(run())
    trace = {k: [d for d in v if d["topic"] == "trace"] for k, v in got.items()}
    for station in ("a", "b"):
        assert [d["data"]["i"] for d in trace["everyone"] if d["station"] == station] == list(range(N))
    assert [d["data"]["i"] for d in trace["only_a"]] == list(range(N))
    assert {d["station"] for d in got["only_a"]} == {"a"}
    assert slow.dropped >= 2 * N - 8
    assert all(f.lost == 0 and f.malformed == 0 for f in relay.feeds.values())


def session_doc(seq: int, topic: str, data: dict) -> bytes:
    return json.dumps({"station": "a", "topic": topic, "seq": seq, "t_s": float(seq), "wall_s": 1e9 + seq,
                       "data": data}).encode()  # fmt: skip


def test_a_late_viewer_gets_the_whole_session_so_far_and_nothing_of_the_last_one():
    """Points, window closes, events with their times, the open window's progress; a new session starts afresh."""
    feed = StationFeed(entry("a"))
    seq = iter(range(10_000))
    feed.accept(session_doc(next(seq), "state", {"state": "running", "session_uid": "S1"}))
    feed.accept(session_doc(next(seq), "event", {"kind": "note", "message": "old session", "level": "info"}))
    feed.accept(session_doc(next(seq), "state", {"state": "running", "session_uid": "S2"}))
    for k in range(30):  # more points than a browser queue's worth of replays would have kept before
        key = f"P{k:03d}"
        feed.accept(session_doc(next(seq), "window", {"key": key, "event": "open", "elapsed_s": 0.0}))
        feed.accept(session_doc(next(seq), "window", {"key": key, "event": "ref", "elapsed_s": 10.0}))
        feed.accept(session_doc(next(seq), "window", {"key": key, "event": "close", "elapsed_s": 30.0,
                                                      "rate_radps": 0.5 + k}))  # fmt: skip
        feed.accept(session_doc(next(seq), "point", {"point_id": key, "pulses": 49152, "Tm_s": 30.0}))
        feed.accept(session_doc(next(seq), "event", {"kind": "point", "message": key, "level": "info"}))
    feed.accept(session_doc(next(seq), "window", {"key": "P030", "event": "open", "elapsed_s": 0.0}))
    feed.accept(session_doc(next(seq), "window", {"key": "P030", "event": "ref", "elapsed_s": 4.0}))
    history = json.loads(feed.replay()[0])["data"]
    assert history["session_uid"] == "S2"
    assert [d["data"]["point_id"] for d in history["points"]] == [f"P{k:03d}" for k in range(30)]
    assert [d["data"]["rate_radps"] for d in history["closes"]] == [0.5 + k for k in range(30)]
    assert [d["data"]["message"] for d in history["notices"]] == [f"P{k:03d}" for k in range(30)]
    assert all(d["t_s"] > 0 and d["wall_s"] > 1e9 for d in history["notices"])  # station time and UTC of each
    assert [d["data"]["event"] for d in history["window"]] == ["open", "ref"]  # only the open window's
