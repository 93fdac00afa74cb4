"""Request and reply bodies of the panel's API (they are its OpenAPI schema)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from web.history import OUTCOMES
from web.users import ROLES

UID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
SERIAL_PATTERN = r"^[\x20-\x7E]{0,64}$"

# What a form can give a procedure parameter (station/engine/params.py validates the rest): bounded, finite.
Number = Annotated[float, Field(allow_inf_nan=False, ge=-1e15, le=1e15)]
Whole = Annotated[int, Field(ge=-(2**53), le=2**53)]
Text = Annotated[str, Field(max_length=200)]
ParamValue = bool | Whole | Number | Text | Annotated[list[Number], Field(max_length=1000)]
Params = Annotated[dict[Annotated[str, Field(max_length=100)], ParamValue], Field(max_length=100)]


class Problem(BaseModel):
    """Every error reply: what is wrong, in words (for 422: the field, the value and what is allowed)."""

    detail: str


class Login(BaseModel):
    model_config = ConfigDict(extra="forbid")
    username: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=1024)


class Me(BaseModel):
    user: str
    role: Literal[ROLES]  # type: ignore[valid-type]
    csrf: str = Field(description="send it back in the X-CSRF-Token header of every POST")


class PlanRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    procedure: str = Field(min_length=1, max_length=200, description="a name from GET /api/stations/{name}/library")
    params: Params = Field(default_factory=dict)


class StartRequest(PlanRequest):
    instrument_serial: str = Field("", pattern=SERIAL_PATTERN, description="instrument under test")
    confirm: bool = Field(False, description="start a design that the dry run warns about (the operator confirmed)")


class ResumeSessionRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    uid: str = Field(pattern=UID_PATTERN, description="an aborted or failed session of this station's store")


class ActionReply(BaseModel):
    ok: bool = True
    result: Any = None


class StationSummary(BaseModel):
    name: str
    title: str
    relay: dict[str, Any] = Field(description="messages received, lost (seq gaps), restarts, seconds since heard")
    serve_command: str = Field("", description="the command that serves this station as the panel expects it")


class RelayHealth(BaseModel):
    browsers: int = Field(description="browsers connected to /ws/telemetry now")
    dropped: int = Field(description="messages dropped for slow browsers since the panel started")
    queue_size: int = Field(description="messages each browser's queue holds")


class SessionRow(BaseModel):
    uid: str
    created_utc: str
    procedure: str
    instrument_serial: str
    status: Literal[OUTCOMES]  # type: ignore[valid-type]
    n_points: int
    stations: list[str]


class GapReply(BaseModel):
    id: str = Field(description="GET /api/gap/{id}/report gives the HTML report")
    session: dict[str, Any] = Field(description="the session diagnosed: uid, procedure, instrument_serial, "
                                    "created_utc, n_points")  # fmt: skip
    report: dict[str, Any] = Field(description="the piga-gap/1 document")
    shrink: float | None = Field(description="fraction of the held-out gap the chosen effects remove; null: no gap")


class GapStatus(BaseModel):
    running: bool = Field(description="a diagnosis is running (one at a time)")
    last_elapsed_s: float | None = Field(description="how long the last diagnosis took; null: none yet")


ERRORS = {
    400: {"model": Problem, "description": "a body that cannot be parsed (not JSON, broken multipart)"},
    401: {"model": Problem, "description": "not logged in"},
    403: {"model": Problem, "description": "operators only, or missing CSRF token"},
    404: {"model": Problem, "description": "no such station, session or diagnosis"},
    409: {"model": Problem, "description": "the station's state does not allow it"},
    413: {"model": Problem, "description": "an upload over the panel's size limits"},
    422: {"model": Problem, "description": "bad input: the message names the field, the value and what is allowed"},
    429: {"model": Problem, "description": "too many failed logins for this user or address: wait Retry-After s"},
    502: {"model": Problem, "description": "the station refused the panel (configuration fault)"},
    504: {"model": Problem, "description": "the station did not answer"},
}


def errors(*codes: int) -> dict:
    """The documented error replies of an endpoint (JSON, whatever the endpoint's own replies are)."""
    problem = {"application/json": {"schema": {"$ref": "#/components/schemas/Problem"}}}
    return {c: ERRORS[c] | {"content": problem} for c in codes}
