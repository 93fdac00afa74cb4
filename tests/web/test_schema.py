"""Property-based run of every API operation against the panel's OpenAPI schema (schemathesis), as an operator.

The panel is served by uvicorn in front of a real `station serve`, so generated
starts, plans, pauses and emergency stops reach the station: whatever
hypothesis sends, no reply may be a 5xx, every reply must be documented
(status, content type, body schema), and input that breaks the schema must be
refused with a 4xx.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import httpx2
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import positive_data_acceptance

from web.app import create_app
from web.auth import CSRF_HEADER, SESSION_COOKIE
from web.config import PanelConfig, StationEntry

EXAMPLES = 25  # per operation: about 25 operations, under a minute on the 2-core machine


def openapi_document() -> dict:
    """The schema, from an app whose station is a placeholder (the schema does not depend on the configuration).

    Schemathesis needs it when pytest collects the module, before any fixture runs. The run is an
    operator's: the login cookie and CSRF header go with every request, so the security schemes are
    left out of what schemathesis generates (test_api_* check 401 and 403 on every endpoint).
    """
    home = Path(tempfile.mkdtemp(prefix="panel-schema-"))
    entry = StationEntry(name="sim", control="tcp://127.0.0.1:1", telemetry="tcp://127.0.0.1:1",
                         store=home / "s.sqlite", reports=home)  # fmt: skip
    doc = create_app(PanelConfig(users=home / "u.json", audit_log=home / "a.jsonl", stations=(entry,))).openapi()
    for path in doc["paths"].values():
        for operation in path.values():
            operation.pop("security", None)
    return doc


schema = schemathesis.openapi.from_dict(openapi_document())


@pytest.fixture(scope="module")
def panel_config(panel_config):
    """The module's panel, with room for the failed logins that schemathesis generates from one address (the
    throttle itself: tests/web/test_security.py)."""
    return panel_config.model_copy(update={"login_failures_max": 1000})


@pytest.fixture(scope="module")
def login_headers(served_panel, passwords) -> Callable[[], dict]:
    """Headers of a new operator login, as a browser sends them."""

    def headers() -> dict:
        reply = httpx2.post(f"{served_panel}/api/login", json={"username": "olga", "password": passwords["olga"]})
        assert reply.status_code == 200, reply.text
        return {"Cookie": f"{SESSION_COOKIE}={reply.cookies[SESSION_COOKIE]}", CSRF_HEADER: reply.json()["csrf"]}

    return headers


@pytest.fixture(scope="module")
def operator_headers(login_headers) -> dict:
    return login_headers()


@schema.parametrize()
@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
def test_no_operation_answers_5xx_or_off_schema(case, served_panel, operator_headers, login_headers):
    # Schema-valid bodies may still be refused by the station (a procedure's own limits), so a 422 for
    # schema-valid input is right: positive_data_acceptance is the one check left out.
    # A logout ends its own login, not the one every other case uses.
    headers = login_headers() if case.path == "/api/logout" else operator_headers
    case.call_and_validate(base_url=served_panel, headers=headers, excluded_checks=[positive_data_acceptance])
