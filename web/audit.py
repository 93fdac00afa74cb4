"""The panel's audit log: every control action and login, who and when, one JSON line each."""

from __future__ import annotations

import json
import threading
from collections import deque
from datetime import UTC, datetime
from pathlib import Path
from typing import Any


class AuditLog:
    """Append-only JSON lines; each line is flushed before the request is answered."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()

    def record(self, user: str, action: str, **details: Any) -> dict:
        entry = {"t_utc": datetime.now(UTC).isoformat(timespec="milliseconds"), "user": user, "action": action}
        entry |= details
        line = json.dumps(entry, default=str)
        with self._lock, self.path.open("a") as f:
            f.write(line + "\n")
        return entry

    def tail(self, n: int) -> list[dict]:
        """The last n entries, newest last."""
        if not self.path.exists():
            return []
        with self._lock, self.path.open() as f:
            return [json.loads(line) for line in deque(f, maxlen=n) if line.strip()]
