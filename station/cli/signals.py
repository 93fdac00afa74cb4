"""Signals of a console run, with bluesky's semantics.

- The first Ctrl-C (SIGINT) asks the engine to pause at its next safe point (before
  a measurement, or at a checkpoint) and, once paused, asks the operator: resume or
  abort (an empty answer or end of input aborts).
- A second Ctrl-C while pausing, paused or asking aborts: the open window is
  aborted and the table ramps to rest.
- SIGTERM aborts at once, the same way.

Nothing is raised into the main thread (no KeyboardInterrupt, no traceback). The
handlers only queue the signal (queue.SimpleQueue.put is reentrant): a handler runs
between two bytecodes of whatever the main thread was doing, even another handler
still inside the engine's lock, so taking a lock there can deadlock the run (a second
Ctrl-C 50 ms after the first once did). A thread of their own calls the controller,
whose supervisor bounds how long the abort may take
(station.engine.supervisor.ABORT_GRACE_S), and the run ends `aborted` with every
finished point kept, resumable with `station resume`.
"""

from __future__ import annotations

import queue
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import TextIO

from station.cli.controller import StationController
from station.clock import host_clock
from station.engine.runner import FINAL_STATES, State

PAUSE_WAIT_POLL_S = 0.1


class RunSignals:
    """Install the handlers for the duration of a run (main thread only); restore the previous ones after."""

    def __init__(
        self, controller: StationController, *, ask: Callable[[str], str] | None = None, out: TextIO | None = None
    ) -> None:
        self.controller = controller
        self.out = out or sys.stderr
        self.ask = ask or self._ask_on_err
        self.interrupts = 0
        self.aborted_by: str | None = None
        self._previous: dict[int, object] = {}
        self._prompt: threading.Thread | None = None
        self._received: queue.SimpleQueue[int | None] = queue.SimpleQueue()
        self._handler: threading.Thread | None = None

    def __enter__(self) -> RunSignals:
        if threading.current_thread() is threading.main_thread():
            self._handler = threading.Thread(target=self._handle, name="run-signals", daemon=True)
            self._handler.start()
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._queue)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]
        self._previous.clear()
        if self._handler is not None:
            self._received.put(None)
            self._handler.join()
            self._handler = None

    def _queue(self, signum: int, frame: FrameType | None) -> None:
        self._received.put(signum)

    def _handle(self) -> None:
        """The signals in the order they came, until the run's end (None)."""
        while (signum := self._received.get()) is not None:
            if signum == signal.SIGINT:
                self._on_sigint()
            else:
                self._abort("SIGTERM")

    def _ask_on_err(self, prompt: str) -> str:
        """input(), but the prompt on stderr with the progress (input() writes it to stdout, into the facts)."""
        print(prompt, end="", file=self.out, flush=True)
        line = sys.stdin.readline()
        if not line:
            raise EOFError
        return line

    def _say(self, text: str) -> None:
        print(f"\n{text}", file=self.out, flush=True)

    def _abort(self, why: str) -> None:
        self.aborted_by = why
        self._say(f"{why}: aborting (the window is aborted, the table ramps to rest; the session stays resumable)")
        self.controller.abort()

    def _on_sigint(self) -> None:
        self.interrupts += 1
        if self.interrupts > 1:
            self._abort("second Ctrl-C")
            return
        self._say("Ctrl-C: pausing at the next safe point (Ctrl-C again to abort)")
        self.controller.pause()
        self._prompt = threading.Thread(target=self._ask_when_paused, name="pause-prompt", daemon=True)
        self._prompt.start()

    def _ask_when_paused(self) -> None:
        """Once paused, ask resume or abort (in its own thread: a second Ctrl-C is still handled)."""
        while (state := self.controller.engine.progress.state) not in (State.PAUSED, *FINAL_STATES):
            if self.aborted_by is not None:
                return
            host_clock().sleep_s(PAUSE_WAIT_POLL_S)
        if state != State.PAUSED or self.aborted_by is not None:
            return
        try:
            answer = self.ask("paused at a safe point: [r]esume or [a]bort? ").strip().lower()
        except (EOFError, OSError):
            answer = ""
        if self.aborted_by is not None:
            return
        if answer in ("r", "resume"):
            self.interrupts = 0  # the next Ctrl-C pauses again
            self._say("resuming")
            self.controller.resume()
        else:
            self._abort(f"answer {answer!r}" if answer else "no answer")
