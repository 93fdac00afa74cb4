"""A real simulated station (`station serve` in a subprocess) and the panel in front of it, for the web tests.

Every module that asks gets its own station on free ports, so that one
module's runs (schemathesis starts and stops sessions at random) never
disturb another's.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from fastapi.testclient import TestClient

from station.cli.panel import panel_server
from station.control_channel import TOKEN_FILE, ControlClient, ensure_token
from web.app import create_app
from web.config import PanelConfig, StationEntry
from web.users import UserBook

STATION_START_S = 60.0  # a loaded 2-core machine starts the emulators in a few seconds
PASSWORDS = {"olga": "operator-pass-1", "victor": "viewer-pass-1"}
ROLES = {"olga": "operator", "victor": "viewer"}
QUICK = {"positions_deg": [0, 72, 144, 216, 288], "freqs_hz": [8, 9, 10], "window_s": 30}  # 20 points, identifiable
PROCEDURE = "integral_precession"
FINAL = ("finished", "aborted", "estopped", "failed")
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic"]  # fmt: skip
SCREENSHOTS = Path(__file__).resolve().parent / "screenshots"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class StationProcess:
    name: str
    control: str
    telemetry: str
    out: Path
    proc: subprocess.Popen

    @property
    def entry(self) -> StationEntry:
        return StationEntry(name=self.name, title=f"Test station {self.name}", control=self.control,
                            telemetry=self.telemetry, store=self.out / "station.sqlite", reports=self.out)  # fmt: skip

    def client(self) -> ControlClient:
        """A client of the station's control channel with its token and keys (close it after use)."""
        return ControlClient(self.control, token=ensure_token(self.out / TOKEN_FILE), timeout_s=10.0,
                             keys_dir=self.entry.telemetry_keys_dir())  # fmt: skip

    def wait_until_idle(self, timeout_s: float = 120.0) -> dict:
        """Poll the control channel until no run is under way; the last status."""
        client = self.client()
        try:
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                reply = client.request("status")
                if reply["ok"] and not reply["result"]["busy"]:
                    return reply["result"]
                time.sleep(0.2)
        finally:
            client.close()
        raise AssertionError(f"station {self.name} still busy after {timeout_s} s")


def start_station(out: Path, name: str = "sim", speed: float | None = None) -> StationProcess:
    control, telemetry = f"tcp://127.0.0.1:{free_port()}", f"tcp://127.0.0.1:{free_port()}"
    cmd = [sys.executable, "-m", "station.cli.cli", "serve", "--out", str(out), "--name", name, "--control", control,
           "--telemetry", telemetry, *(["--speed", str(speed)] if speed else [])]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + STATION_START_S
    line = proc.stdout.readline()  # the serve command prints one line once it listens
    if "control" not in line or time.monotonic() > deadline:
        proc.kill()
        raise AssertionError(f"station serve did not start: {line}{proc.stdout.read()}")
    return StationProcess(name, control, telemetry, out, proc)


def stop_process(proc: subprocess.Popen, timeout_s: float = 40.0) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def write_users(path: Path) -> Path:
    book = UserBook(path)
    for name, password in PASSWORDS.items():
        book.add(name, ROLES[name], password)
    return path


@pytest.fixture(scope="module")
def station(tmp_path_factory) -> Iterator[StationProcess]:
    st = start_station(tmp_path_factory.mktemp("station"))
    yield st
    stop_process(st.proc)


@pytest.fixture(scope="module")
def panel_config(station, tmp_path_factory) -> PanelConfig:
    home = tmp_path_factory.mktemp("panel")
    return PanelConfig(users=write_users(home / "users.json"), audit_log=home / "audit.jsonl",
                       stations=(station.entry,))  # fmt: skip


@pytest.fixture(scope="module")
def app_client(panel_config) -> Iterator[TestClient]:
    with TestClient(create_app(panel_config), base_url="http://127.0.0.1") as client:
        yield client


def login(client: TestClient, name: str) -> TestClient:
    """Log `client` in as `name`; its CSRF token is then sent with every request."""
    reply = client.post("/api/login", json={"username": name, "password": PASSWORDS[name]})
    assert reply.status_code == 200, reply.text
    client.headers["X-CSRF-Token"] = reply.json()["csrf"]
    return client


@pytest.fixture(scope="session")
def tools() -> SimpleNamespace:
    """This file's helpers, for the test modules (which cannot import conftest)."""
    return SimpleNamespace(start_station=start_station, stop_process=stop_process, free_port=free_port,
                           write_users=write_users, serving_panel=serving_panel, serving_site=serving_site,
                           screenshots=SCREENSHOTS)  # fmt: skip


@pytest.fixture(scope="session")
def passwords() -> dict[str, str]:
    return PASSWORDS


@pytest.fixture(scope="session")
def quick() -> dict:
    """Parameters of a quick seed-000 session that can still be identified."""
    return dict(QUICK)


@pytest.fixture(scope="session")
def log_in() -> Callable[[TestClient, str], TestClient]:
    return login


@pytest.fixture(scope="module")
def as_user(app_client) -> Callable[[str], TestClient]:
    """A new client of the module's panel logged in as `name` (the panel's lifespan runs in app_client)."""
    return lambda name: login(TestClient(app_client.app, base_url="http://127.0.0.1"), name)


@contextmanager
def serving_panel(config: PanelConfig) -> Iterator[str]:
    """The panel of `config` served by uvicorn on a free port (in a thread) while the block runs; its base URL."""
    port = free_port()
    server = panel_server(config, "127.0.0.1", port)
    thread = threading.Thread(target=server.run, name="panel", daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "the panel did not start"
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10)


@contextmanager
def serving_site(home: Path, speed: float) -> Iterator[dict]:
    """A served simulated station at `speed` and a panel on it while the block runs: {"url", "station"}."""
    station = start_station(home / "station", speed=speed)
    config = PanelConfig(users=write_users(home / "users.json"), audit_log=home / "audit.jsonl",
                         stations=(station.entry,))  # fmt: skip
    try:
        with serving_panel(config) as url:
            yield {"url": url, "station": station}
    finally:
        stop_process(station.proc)


@pytest.fixture(scope="module")
def served_panel(panel_config) -> Iterator[str]:
    """The module's panel served by uvicorn on a free port (in a thread); its base URL."""
    with serving_panel(panel_config) as url:
        yield url


@pytest.fixture(scope="module")
def browser():
    """Headless Debian Chromium under Playwright (no browser download); screenshots go to SCREENSHOTS."""
    from playwright.sync_api import sync_playwright

    assert CHROMIUM.exists(), "Debian's chromium is missing: run web/setup.sh (apt-get install chromium)"
    SCREENSHOTS.mkdir(exist_ok=True)
    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def logged_in_page(browser, passwords) -> Callable[..., Any]:
    """A new browser context's page on the panel at `url`, logged in as `name` (close its context after use)."""

    def open_page(url: str, name: str, viewport: dict | None = None, timeout_ms: float = 30_000) -> Any:
        page = browser.new_context(viewport=viewport or {"width": 1400, "height": 1000}).new_page()
        page.set_default_timeout(timeout_ms)
        page.goto(f"{url}/login")
        page.fill("input[name=username]", name)
        page.fill("input[name=password]", passwords[name])
        page.click("button[type=submit]")
        page.wait_for_url(f"{url}/")
        return page

    return open_page
