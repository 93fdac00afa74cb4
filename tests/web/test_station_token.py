"""A station served with a control token (--token-env): the panel forwards the token named by its token_env."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from station.cli.cli import main
from web.app import create_app
from web.config import PanelConfig, StationEntry

TOKEN_VAR = "BENCH_STATION_TOKEN"
TOKEN = "a-long-random-station-token"


@pytest.fixture(scope="module")
def token_station(tmp_path_factory, tools) -> Iterator[StationEntry]:
    out = tmp_path_factory.mktemp("token-station")
    control, telemetry = f"tcp://127.0.0.1:{tools.free_port()}", f"tcp://127.0.0.1:{tools.free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "station.cli.cli", "serve", "--out", str(out), "--name", "sim", "--control", control,
         "--telemetry", telemetry, "--token-env", TOKEN_VAR],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=os.environ | {TOKEN_VAR: TOKEN},
    )  # fmt: skip
    assert "control" in proc.stdout.readline()
    yield StationEntry(name="sim", control=control, telemetry=telemetry, store=out / "station.sqlite", reports=out,
                       token_env=TOKEN_VAR)  # fmt: skip
    tools.stop_process(proc)


@pytest.mark.parametrize(("value", "status"), [(TOKEN, 200), ("a-wrong-token", 502)])
def test_the_panel_sends_the_token_from_its_environment(token_station, tmp_path, monkeypatch, log_in, tools, value,
                                                        status):  # fmt: skip
    monkeypatch.setenv(TOKEN_VAR, value)
    users = tools.write_users(tmp_path / "users.json")
    config = PanelConfig(users=users, audit_log=tmp_path / "audit.jsonl", stations=(token_station,))
    client = log_in(TestClient(create_app(config), base_url="http://127.0.0.1"), "olga")
    reply = client.get("/api/stations/sim/status")
    assert reply.status_code == status, reply.text
    if status == 502:
        assert reply.json()["detail"] == "station sim: bad or missing control token"


def test_a_token_variable_that_is_not_set_stops_the_panel_at_start(token_station, tmp_path, monkeypatch, capsys, tools):
    monkeypatch.delenv(TOKEN_VAR, raising=False)
    config = tmp_path / "panel.toml"
    e = token_station
    config.write_text(
        f'[[stations]]\nname = "sim"\ncontrol = "{e.control}"\ntelemetry = "{e.telemetry}"\n'
        f'store = "{e.store}"\nreports = "{e.reports}"\ntoken_env = "{TOKEN_VAR}"\n'
    )
    t0 = time.monotonic()
    assert main(["panel", "--config", str(config), "--port", str(tools.free_port())]) == 2
    assert f"token_env {TOKEN_VAR}: that variable is not set" in capsys.readouterr().err
    assert time.monotonic() - t0 < 10
