"""Station telemetry to browsers: one zmq SUB per station, fanned out to a bounded queue per browser.

The SUB sockets live on the panel's event loop (zmq.asyncio). Every message
is checked (station, seq) and its text handed unchanged to each browser's
queue; a full queue drops its oldest message and counts the drop, so a slow
browser loses its own backlog and never slows the others or the station.
The latest message of each lasting topic is kept, and the session so far
(its points, window closes, events and faults, the open window's progress and
the last display traces: `SessionHistory`), so that a browser that connects
mid-session is sent the state and the session's history at once, as one
`history` document followed by the latest lasting messages.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import zmq
import zmq.asyncio

from station.telemetry import CLIENT_CERT, curve_client
from web.config import StationEntry

QUEUE_SIZE = 256  # messages per browser: about 5 s of a station's telemetry
LASTING_TOPICS = ("state", "progress", "status", "window", "motion", "point", "analysis")
SESSION_TOPICS = ("window", "point", "analysis")  # lasting messages of one session: a new session drops them
HISTORY_POINTS = 2000  # points and window closes of the session kept for a browser that joins late
HISTORY_NOTICES = 500  # events and faults of the session
HISTORY_WINDOW = 1000  # progress messages of the open window
HISTORY_TRACES = 20  # display traces: about 2 s of wall time


@dataclass
class SessionHistory:
    """What a late viewer needs of the session under way: its points, window closes, events and faults, the open
    window's progress and the last display traces (telemetry documents as received, bounded)."""

    session_uid: str = ""
    points: deque[dict] = field(default_factory=lambda: deque(maxlen=HISTORY_POINTS))
    closes: deque[dict] = field(default_factory=lambda: deque(maxlen=HISTORY_POINTS))
    notices: deque[dict] = field(default_factory=lambda: deque(maxlen=HISTORY_NOTICES))
    window: deque[dict] = field(default_factory=lambda: deque(maxlen=HISTORY_WINDOW))
    traces: deque[dict] = field(default_factory=lambda: deque(maxlen=HISTORY_TRACES))

    def add(self, doc: dict) -> None:
        topic, data = doc["topic"], doc.get("data")
        data = data if isinstance(data, dict) else {}
        uid = data.get("session_uid")
        if uid and uid != self.session_uid:  # a new session: the last one's history goes
            for part in (self.points, self.closes, self.notices, self.window, self.traces):
                part.clear()
            self.session_uid = uid
        if topic == "point":
            self.points.append(doc)
        elif topic in ("event", "fault"):
            self.notices.append(doc)
        elif topic == "trace":
            self.traces.append(doc)
        elif topic == "window":
            if data.get("event") == "open":
                self.window.clear()
            self.window.append(doc)
            if data.get("event") == "close":
                self.closes.append(doc)
        elif topic == "motion" and not data.get("freq_hz"):
            self.traces.clear()  # at rest: the last motion is no longer the table's

    def document(self, station: str) -> dict:
        """The `history` message: {"station", "topic": "history", "seq": None, "wall_s", "data": {...}}."""
        data = {"session_uid": self.session_uid, "points": list(self.points), "closes": list(self.closes),
                "notices": list(self.notices), "window": list(self.window), "traces": list(self.traces)}  # fmt: skip
        return {"station": station, "topic": "history", "seq": None, "wall_s": time.time(), "data": data}


class BrowserQueue:
    """One browser's bounded queue of message texts; the oldest is dropped (and counted) when full."""

    def __init__(self, maxsize: int = QUEUE_SIZE, stations: Iterable[str] | None = None) -> None:
        self._queue: asyncio.Queue[str] = asyncio.Queue(maxsize)
        self.stations = set(stations) if stations is not None else None
        self.dropped = 0

    def offer(self, text: str) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        self._queue.put_nowait(text)

    async def batch(self, limit: int) -> list[str]:
        """Wait for one message, then take whatever else is waiting, up to limit."""
        out = [await self._queue.get()]
        while len(out) < limit and not self._queue.empty():
            out.append(self._queue.get_nowait())
        return out


@dataclass
class StationFeed:
    """What the panel has heard from one station."""

    station: StationEntry
    received: int = 0
    lost: int = 0  # messages the seq numbers say never arrived (slow joiner, high-water mark)
    restarts: int = 0  # the publisher started again (seq went back)
    malformed: int = 0
    last_seq: int | None = None
    last_heard: float | None = None  # time.time() of the last message
    latest: dict[str, str] = field(default_factory=dict)
    history: SessionHistory = field(default_factory=SessionHistory)

    def accept(self, body: bytes) -> str | None:
        """The message text if it is a well-formed message of this station (seq accounted); None otherwise."""
        try:
            doc = json.loads(body)
            seq, topic = int(doc["seq"]), str(doc["topic"])
            ok = doc["station"] == self.station.name
        except (ValueError, KeyError, TypeError):
            ok = False
        if not ok:
            self.malformed += 1
            return None
        if self.last_seq is not None:
            if seq > self.last_seq + 1:
                self.lost += seq - self.last_seq - 1
            elif seq <= self.last_seq:
                self.restarts += 1
        self.last_seq = seq
        self.last_heard = time.time()
        self.received += 1
        text = body.decode()
        session_uid = self.history.session_uid
        self.history.add(doc)
        if self.history.session_uid != session_uid:  # a new session: the last one's window and results go
            for old in SESSION_TOPICS:
                self.latest.pop(old, None)
        if topic in LASTING_TOPICS:
            self.latest[topic] = text
        return text

    def replay(self) -> list[str]:
        """What a browser that connects now needs first: the session's history (one document), then the latest
        lasting messages."""
        return [json.dumps(self.history.document(self.station.name)), *self.latest.values()]

    def stats(self) -> dict:
        age = None if self.last_heard is None else max(time.time() - self.last_heard, 0.0)
        return {"received": self.received, "lost": self.lost, "restarts": self.restarts,
                "malformed": self.malformed, "last_seq": self.last_seq, "silent_s": age}  # fmt: skip


class TelemetryRelay:
    """SUB sockets of every configured station and the browsers' queues."""

    def __init__(self, stations: Iterable[StationEntry], queue_size: int = QUEUE_SIZE) -> None:
        self.feeds = {s.name: StationFeed(s) for s in stations}
        self.queue_size = queue_size
        self._browsers: set[BrowserQueue] = set()
        self._dropped_by_gone = 0  # drops of browsers that have disconnected
        self._ctx: zmq.asyncio.Context | None = None
        self._tasks: list[asyncio.Task] = []

    @property
    def browsers(self) -> int:
        return len(self._browsers)

    @property
    def dropped(self) -> int:
        """Messages dropped for slow browsers since the panel started."""
        return self._dropped_by_gone + sum(q.dropped for q in self._browsers)

    def start(self) -> None:
        """Connect a SUB to every station (on the running event loop)."""
        self._ctx = zmq.asyncio.Context()
        self._tasks = [asyncio.create_task(self._listen(feed), name=f"sub-{n}") for n, feed in self.feeds.items()]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if self._ctx is not None:
            self._ctx.destroy(linger=0)

    def subscribe(self, stations: Iterable[str] | None = None, queue_size: int | None = None) -> BrowserQueue:
        """A new browser's queue, filled first with what it needs to show the present state."""
        queue = BrowserQueue(queue_size or self.queue_size, stations)
        for name, feed in self.feeds.items():
            if queue.stations is None or name in queue.stations:
                for text in feed.replay():
                    queue.offer(text)
        self._browsers.add(queue)
        return queue

    def unsubscribe(self, queue: BrowserQueue) -> None:
        if queue in self._browsers:
            self._browsers.discard(queue)
            self._dropped_by_gone += queue.dropped

    async def _listen(self, feed: StationFeed) -> None:
        assert self._ctx is not None
        sock = self._ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, 0)
        keys = feed.station.telemetry_keys_dir()
        if (keys / f"{CLIENT_CERT}.key_secret").is_file():  # the station's telemetry is for its keys' holders only
            curve_client(sock, keys)
        sock.connect(feed.station.telemetry)
        sock.subscribe(f"{feed.station.name}.".encode())
        name = feed.station.name
        try:
            while True:
                frames = await sock.recv_multipart()
                text = feed.accept(frames[-1])
                if text is None:
                    continue
                for queue in self._browsers:
                    if queue.stations is None or name in queue.stations:
                        queue.offer(text)
        finally:
            sock.close()
