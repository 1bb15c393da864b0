"""Schema fuzzing (issue #13, defect 3): schemathesis generates requests for every operation of the published
OpenAPI schema, valid and invalid ones, for every role (no token, annotator, reviewer, admin), and runs all its
checks on the answers: no 5xx, every status documented, bodies and headers as the schema says, invalid input
refused, valid input accepted, authentication not ignored.

Bounded for the test suite: HANDLOOP_FUZZ_EXAMPLES examples per operation, role and mode (valid, invalid;
default 12). To fuzz longer, without the CLI:
`HANDLOOP_FUZZ_EXAMPLES=500 python -m pytest tests/backend/api/test_schema_fuzz.py -q`. It runs on both databases:
PostgreSQL's integers and text are narrower than SQLite's (ids beyond 2**31-1, NUL characters), and only fuzzing
there found the routes that let them through.
"""

from __future__ import annotations

import os

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.core.parameters import ParameterLocation

from backend.models.enums import Role
from backend.services.display import scene_tickets

EXAMPLES = int(os.environ.get("HANDLOOP_FUZZ_EXAMPLES", "12"))
# Valid bodies the server must still refuse with 422 for what no schema can say: an import names a folder on
# the server, and whether it holds a capture is known only there; a guidelines image is bytes, and whether they are
# a PNG, JPEG, WebP or GIF is known only by decoding them (the other checks still run).
STATE_DEPENDENT = {"POST /api/admin/imports": "positive_data_acceptance",
                   "POST /api/admin/guidelines/images": "positive_data_acceptance"}
ROLES = [None, Role.annotator, Role.reviewer, Role.admin]


def _fuzz(operation, mode: GenerationMode, send) -> list[str]:
    """Failures (one line each, first per distinct message) of `EXAMPLES` generated cases."""
    failures: dict[str, str] = {}

    @given(case=operation.as_strategy(generation_mode=mode))
    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    def run(case) -> None:
        try:
            send(case)
        except Exception as exc:  # schemathesis's failures (FailureGroup), or an error of the app
            text = str(exc).strip() or type(exc).__name__
            codes = " ".join(sorted({w for w in text.split() if w[:2] == "ST" and w[2:].isdigit()})) or text[:200]
            failures.setdefault(codes, f"{operation.label} [{mode.value}]: {text[:1500]}")

    try:
        run()
    except Unsatisfiable:
        if mode is GenerationMode.POSITIVE:
            raise
        # nothing to make invalid (no parameters, no body)
    return list(failures.values())


@pytest.mark.parametrize("role", ROLES, ids=lambda r: "anonymous" if r is None else r.value)
def test_every_operation_answers_as_documented(env, h, role):
    h.seed(env, frames=3, cameras=2)  # ids 1.. exist, so some generated requests reach real rows
    schema = schemathesis.openapi.from_asgi("/openapi.json", env.client.app)
    checks = schemathesis.checks.CHECKS.get_all()
    names = {check.__name__: check for check in checks}
    assert set(STATE_DEPENDENT.values()) <= set(names)
    headers = env.headers(role) if role is not None else {}

    def send(case) -> None:
        if case.path.startswith("/api/viewer/") and role is not None:  # its credential is a ticket, not a token
            case.query = {**(case.query or {}), "ticket": scene_tickets.issue(
                env.settings.signing_key, env.user_ids[role], 1, 1, token_version=0)}
        # A case whose headers were made invalid (e.g. Authorization left out) is sent as generated.
        negated = case.meta is not None and any(
            component.mode.is_negative for location, component in case.meta.components.items()
            if location == ParameterLocation.HEADER)
        skipped = STATE_DEPENDENT.get(case.operation.label)
        case.call_and_validate(headers=None if negated else headers,
                               checks=[c for c in checks if c.__name__ != skipped])

    failures, operations = [], 0
    for result in schema.get_all_operations():
        operation = result.ok()
        operations += 1
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            failures += _fuzz(operation, mode, send)
    assert operations >= 30
    assert not failures, f"{len(failures)} failures:\n\n" + "\n\n".join(failures)
