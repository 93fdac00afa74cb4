"""The panel's configuration file (config/panel.toml): where it listens, its stations, stores and secrets' places.

Relative paths are taken from the directory the panel is started in, as for
`station serve --out out`. Secrets are never in this file: passwords live
hashed in the users file, the stations' control tokens in environment
variables named here.
"""

from __future__ import annotations

import ipaddress
import re
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from station.errors import InputError
from station.tomlfile import read_toml
from web.auth import MAX_FAILURES

NAME_PATTERN = r"^[A-Za-z0-9_-]{1,40}$"


class PanelConfigError(InputError):
    """A panel configuration file that is unreadable or holds a bad key or value."""


class StationEntry(BaseModel):
    """One station under `station serve`: its control and telemetry endpoints, store and reports."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=NAME_PATTERN, description="the --name of `station serve` (telemetry topic prefix)")
    title: str = ""
    control: str = Field(pattern=r"^(tcp|ipc|inproc)://", description="zmq REP endpoint of the control channel")
    telemetry: str = Field(pattern=r"^(tcp|ipc|inproc)://", description="zmq PUB endpoint of its telemetry")
    store: Path = Field(description="its SQLite session store (the --db of `station serve`)")
    reports: Path = Field(description="its --out directory, where report-<uid>.html files are written")
    token_env: str = Field("", description="environment variable holding its control token (instead of the file)")
    token_file: Path | None = Field(None, description="its control token file (default: control.token beside its "
                                    "store, where `station serve --out DIR` creates it)")  # fmt: skip

    telemetry_keys: Path | None = Field(None, description="its telemetry CURVE keys (default: telemetry-keys "
                                        "beside its store, where `station serve --out DIR` makes them)")  # fmt: skip

    def control_token_file(self) -> Path:
        return self.token_file or self.store.parent / "control.token"

    def telemetry_keys_dir(self) -> Path:
        return self.telemetry_keys or self.store.parent / "telemetry-keys"


class CentralEntry(BaseModel):
    """The lab's central calibration history (`station sync`): read instead of the stations' stores."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    url: str = Field(pattern=r"^postgresql(\+psycopg)?://", description="the PostgreSQL database (no password here: "
                     "~/.pgpass or PGPASSWORD)")  # fmt: skip
    arrays: Path = Field(description="the lab's array root, where `station sync --arrays` puts the raw arrays")

    @field_validator("url")
    @classmethod
    def _no_password(cls, url: str) -> str:
        if re.match(r"^[^:]+://[^/@]*:[^/@]*@", url):
            raise ValueError("the URL holds a password: put it in ~/.pgpass or PGPASSWORD, not in the panel file")
        return url


class PanelConfig(BaseModel):
    """The whole panel configuration."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    host: str = "127.0.0.1"
    port: int = Field(8080, ge=0, le=65535)
    users: Path = Field(Path("out/panel/users.json"), description="users and password hashes (not in the repository)")
    audit_log: Path = Path("out/panel/audit.jsonl")
    twin: Path | None = Field(None, description="twin configuration TOML for the gap diagnosis (default: embedded)")
    secure_cookies: bool = Field(False, description="mark the session cookie Secure (behind HTTPS)")
    # Compressing every frame for every browser costs the panel 3-4 times the CPU of relaying (BENCHMARKS.md),
    # CPU that the station's real-time work on the same machine needs; it pays only over slow links.
    websocket_compression: bool = Field(False, description="permessage-deflate for remote browsers on slow links")
    stations: tuple[StationEntry, ...] = Field(min_length=1)
    central: CentralEntry | None = Field(None, description="read the history from the central database (issue 16)")
    login_failures_max: int = Field(
        MAX_FAILURES, ge=1, le=1000,
        description="wrong passwords per name from one address, and per address, in 15 min before 429",
    )  # fmt: skip
    # No proxy is trusted unless named: X-Forwarded-For from anyone else is ignored (not only from afar: with the
    # panel on 127.0.0.1, trusting loopback would let every local process and SSH tunnel claim any address, to
    # escape the login throttle and to write false addresses into the audit log).
    trusted_proxies: tuple[str, ...] = Field(
        (), description="addresses or networks (CIDR) of the reverse proxies whose X-Forwarded-For names the "
        "client (the login throttle's and the audit log's address); default none: the TCP peer's address"
    )  # fmt: skip

    @field_validator("stations")
    @classmethod
    def _unique_names(cls, stations: tuple[StationEntry, ...]) -> tuple[StationEntry, ...]:
        names = [s.name for s in stations]
        if len(set(names)) != len(names):
            raise ValueError(f"station names must be unique, got {names}")
        return stations

    @field_validator("trusted_proxies")
    @classmethod
    def _ip_networks(cls, proxies: tuple[str, ...]) -> tuple[str, ...]:
        for value in proxies:
            try:
                ipaddress.ip_network(value, strict=False)
            except ValueError:
                raise ValueError(f"{value!r} is not allowed: an IP address (127.0.0.1, ::1) or network in CIDR "
                                 "form (10.0.0.0/8) of a proxy in front of the panel") from None  # fmt: skip
        return proxies

    @model_validator(mode="after")
    def _twin_exists(self) -> PanelConfig:
        if self.twin is not None and not self.twin.is_file():
            raise ValueError(f"twin = {str(self.twin)!r}: no such file")
        return self

    @classmethod
    def from_toml(cls, path: str | Path) -> PanelConfig:
        """Read and validate; PanelConfigError names the file, the key and what is wrong."""
        path = Path(path)
        doc = read_toml(path, "panel config", PanelConfigError)
        panel = doc.pop("panel", {})
        try:
            return cls.model_validate(panel | doc)
        except ValidationError as exc:
            raise PanelConfigError(f"{path}: {describe_errors(exc.errors())}") from None


def describe_errors(errors: list) -> str:
    """Pydantic's errors as one line each: `where: what (value)`."""
    lines = []
    for e in errors:
        where = ".".join(str(x) for x in e.get("loc", ())) or "(document)"
        value = f" (got {_short(e['input'])})" if "input" in e and not isinstance(e["input"], dict | list) else ""
        lines.append(f"{where}: {e['msg']}{value}")
    return "; ".join(lines)


def _short(value, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
