"""Bounded schemathesis fuzzing of the HTTP service: no generated request gets a 5xx.

Runs against a real server on a loopback port; skipped when schemathesis is not installed
(it is not a dependency of the project: ``pip install schemathesis`` to run it).
"""

from __future__ import annotations

import pytest

schemathesis = pytest.importorskip("schemathesis")

from hypothesis import HealthCheck, given, settings  # noqa: E402  (after the skip)
from schemathesis.checks import not_a_server_error  # noqa: E402

from service.http import Settings  # noqa: E402

from .test_http import running_server  # noqa: E402

EXAMPLES_PER_OPERATION = 25


def test_no_generated_request_gets_a_server_error() -> None:
    with running_server(Settings(workers=2, queue_size=16)) as base:
        schema = schemathesis.openapi.from_url(f"{base}/openapi.json")
        operations = [result.ok() for result in schema.get_all_operations()]
        assert {operation.path for operation in operations} >= {"/v1/detect", "/metrics"}
        for operation in operations:

            @given(case=operation.as_strategy())
            @settings(
                max_examples=EXAMPLES_PER_OPERATION,
                deadline=None,
                derandomize=True,
                suppress_health_check=list(HealthCheck),
                database=None,
            )
            def fuzz(case) -> None:
                case.call_and_validate(checks=[not_a_server_error], timeout=20)

            fuzz()
