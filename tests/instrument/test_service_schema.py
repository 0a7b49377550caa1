"""Schemathesis against the service's own OpenAPI schema: generated requests, no server errors.

The default run is bounded (a few examples per operation); ``-m slow`` runs many more.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis.checks import not_a_server_error
from service_support import build_tiny_table

from solitonde.instrument.service.app import build_app
from solitonde.instrument.service.settings import Settings

_DIR = Path(tempfile.mkdtemp(prefix="solitonde-schema-"))
# A real (tiny) model table, so that /v1/invert and the estimate path run their real code.
# Small limits keep generated requests cheap; they are what the schema states, so the generator
# explores the edges of the same limits the server enforces. (Schemathesis runs the lifespan.)
APP = build_app(Settings(store_path=_DIR / "store.sqlite",
                         table_path=build_tiny_table(_DIR / "table.h5"),
                         max_samples_per_shot=5000, max_shots_per_request=4,
                         max_simulation_cost=5e6))
schema = schemathesis.openapi.from_asgi("/openapi.json", APP)


def no_server_error(ctx, response, case):  # the signature schemathesis calls checks with
    """No 5xx, except the documented 503 of /v1/invert while no model table is loaded."""
    service = APP.state.service
    if (response.status_code == 503 and case.path == "/v1/invert" and service is not None
            and not service.tables.loaded):
        assert response.json()["field"] == "table"
        return None
    return not_a_server_error(ctx, response, case)


CHECKS = [no_server_error]


# One test per operation, named by it: schemathesis's own parametrisation gives every
# operation the same test id, which a parallel run (pytest-xdist) collapses to one. Requests
# valid and invalid against the schema, as its parametrisation generates them.
OPERATIONS = [result.ok() for result in schema.get_all_operations()]


def cases(operation):
    return st.one_of(*(operation.as_strategy(mode) for mode in schema.config.generation.modes))


@pytest.mark.parametrize("operation", OPERATIONS, ids=lambda op: op.label)
@settings(max_examples=6, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_no_server_error(operation, data) -> None:
    """Every operation, a few generated requests each: never a 5xx."""
    data.draw(cases(operation)).call_and_validate(checks=CHECKS)


@pytest.mark.slow
@pytest.mark.parametrize("operation", OPERATIONS, ids=lambda op: op.label)
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_no_server_error_long(operation, data) -> None:
    """The same with 150 examples per operation (about a minute per operation)."""
    data.draw(cases(operation)).call_and_validate(checks=CHECKS)
