"""The panel's side of each station's control channel: requests off the event loop, refusals as HTTP errors."""

from __future__ import annotations

import asyncio
import os
from typing import Any

from fastapi import HTTPException

from station.control_channel import ControlClient, ControlError, ensure_token
from web.config import PanelConfigError, StationEntry

# The station's error types (station/cli/control.py) as HTTP statuses; any other refusal is a conflict (409).
HTTP_STATUS = {
    "ParameterError": 422,  # the message names the parameter, the value and what is allowed
    "ValidationError": 422,
    "RefusedDesignError": 422,  # a design that cannot work, one line per problem (station/engine/design_checks.py)
    "ProcedureError": 422,
    "KeyError": 422,
    "TypeError": 422,
    "ControlError": 409,  # a run already under way, nothing to resume, ...
    "Unauthorized": 502,  # the panel's control token is not the station's: a configuration fault
    "UnknownCommand": 502,
    "BadRequest": 502,
    "Timeout": 504,
}


class StationLink:
    """One station's control client; blocking requests run in a worker thread."""

    def __init__(self, entry: StationEntry, timeout_s: float = 10.0) -> None:
        self.entry = entry
        token = os.environ.get(entry.token_env) if entry.token_env else None
        if entry.token_env and not token:
            raise PanelConfigError(f"station {entry.name}: token_env {entry.token_env}: that variable is not set")
        self._timeout_s = timeout_s
        self.client: ControlClient | None = None
        if token is not None:
            keys = entry.telemetry_keys_dir()
            self.client = ControlClient(entry.control, token=token, timeout_s=timeout_s, keys_dir=keys)

    def _client(self) -> ControlClient:
        """The client, with the token of the station's token file once the station has made it."""
        if self.client is None:
            path = self.entry.control_token_file()
            try:
                token = ensure_token(path) if path.exists() else None
            except ControlError as exc:
                raise HTTPException(502, f"station {self.entry.name}: {exc}") from None
            if token is None:
                raise HTTPException(502, f"station {self.entry.name}: no control token at {path} (start the station "
                                    "with `station serve`, or set token_file / token_env)")  # fmt: skip
            self.client = ControlClient(self.entry.control, token=token, timeout_s=self._timeout_s,
                                        keys_dir=self.entry.telemetry_keys_dir())  # fmt: skip
        return self.client

    async def request(self, cmd: str, args: dict[str, Any] | None = None, user: str = "") -> Any:
        """The station's result; HTTPException with the station's own message if it refuses."""
        reply = await asyncio.to_thread(self._client().request, cmd, args, user)
        if reply.get("ok"):
            return reply.get("result")
        error = reply.get("error") or {}
        kind = str(error.get("type", "Error"))
        raise HTTPException(HTTP_STATUS.get(kind, 409), f"station {self.entry.name}: {error.get('message', kind)}")

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
