"""What the panel holds while it runs: its configuration, logins, audit log, telemetry relay, stations, history."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Request

from web.audit import AuditLog
from web.auth import LoginSessions, LoginThrottle
from web.config import NAME_PATTERN, PanelConfig
from web.gap import GapDiagnoses
from web.history import History
from web.relay import TelemetryRelay
from web.stations import StationLink
from web.users import LiveUsers


@dataclass
class Panel:
    config: PanelConfig
    logins: LoginSessions
    audit: AuditLog
    relay: TelemetryRelay
    links: dict[str, StationLink]
    history: History
    gaps: GapDiagnoses
    throttle: LoginThrottle

    @classmethod
    def open(cls, config: PanelConfig) -> Panel:
        return cls(
            config=config,
            logins=LoginSessions(users=LiveUsers(config.users)),
            audit=AuditLog(config.audit_log),
            relay=TelemetryRelay(config.stations),
            links={s.name: StationLink(s) for s in config.stations},
            history=History(config.stations, config.central),
            gaps=GapDiagnoses(config.twin),
            throttle=LoginThrottle(max_failures=config.login_failures_max),
        )

    def close(self) -> None:
        for link in self.links.values():
            link.close()
        self.history.close()


def panel(request: Request) -> Panel:
    return request.app.state.panel


def station_link(
    request: Request, name: Annotated[str, Path(pattern=NAME_PATTERN, description="station")]
) -> StationLink:
    """The station of the path; 404 if the panel has no such station."""
    link = panel(request).links.get(name)
    if link is None:
        raise HTTPException(404, f"no station {name!r}; the panel has: {', '.join(panel(request).links)}")
    return link


Link = Annotated[StationLink, Depends(station_link)]
