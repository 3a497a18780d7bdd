"""Schemathesis against the committed contract, openapi/openapi.json, on a live `roadlink serve`:
every operation, with every default check (no 5xx; status codes, content types, headers and
bodies as documented; schema-valid data accepted and invalid data refused; authentication not
ignored; `Allow` on 405; ...), through schemathesis's Python API."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.config import SchemathesisConfig
from schemathesis.config._checks import POSITIVE_DATA_ACCEPTANCE_EXPECTED_STATUSES

from tests.live_server import LiveServer, free_port, roadlink, sqlite_env

pytestmark = pytest.mark.slow

SPEC = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"
# Every check at its defaults, but one: a request valid by the schema may still be a documented
# 422, for what JSON Schema cannot say (distinct sensor ids, an associator's name and parameters,
# a simulation whose settings contradict each other, a cursor the server did not make).
CONFIG = SchemathesisConfig.from_dict(
    {
        "checks": {
            "positive_data_acceptance": {
                "expected-statuses": [*POSITIVE_DATA_ACCEPTANCE_EXPECTED_STATUSES, "422"]
            }
        }
    }
)
schema = schemathesis.openapi.from_path(SPEC, config=CONFIG)

# Bounded and repeatable: a few examples per operation, derived from the test's name rather than
# a random seed, so the run takes well under a minute on 2 cores and a failure reproduces.
# Raise it to explore further.
MAX_EXAMPLES = 15


class Served:
    def __init__(self, url: str, key: str) -> None:
        self.url = url
        self.key = key


# The key goes through schemathesis's auth, not as a header of every call: it then knows which
# requests carry it, and one it sends without (to see that it is refused) goes without. Cases
# are made before the server runs, so they carry this stand-in, swapped for the key at the call.
STAND_IN = "rl_standin_key"


@schema.auth()
class AdminKey:
    def get(self, case: schemathesis.Case, context: schemathesis.AuthContext) -> str:
        return STAND_IN

    def set(self, case: schemathesis.Case, data: str, context: schemathesis.AuthContext) -> None:
        case.headers = {**(case.headers or {}), "Authorization": f"Bearer {data}"}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    directory = tmp_path_factory.mktemp("fuzz")
    # The rate limit would answer most generated requests with 429 (documented, but it tests
    # nothing else), so this server has none.
    # A generated ?wait= or an event stream of a deployment it made holds its request up to
    # the longest wait: one second keeps the run within its time.
    env = sqlite_env(directory, ROADLINK_RATE_LIMIT_PER_SECOND="0", ROADLINK_MAX_WAIT_SECONDS="1")
    live = LiveServer(directory, env, free_port())
    key = roadlink("keys", "create", "--scope", "admin", env=env, cwd=directory).strip()
    live.start(workers=1)
    try:
        yield Served(live.url, key)
    finally:
        live.stop()


@schema.parametrize()
@settings(
    max_examples=MAX_EXAMPLES,
    derandomize=True,
    deadline=None,
    suppress_health_check=list(HealthCheck),
)
def test_every_default_check_passes(case: schemathesis.Case, served: Served) -> None:
    if case.headers and case.headers.get("Authorization") == f"Bearer {STAND_IN}":
        case.headers["Authorization"] = f"Bearer {served.key}"
    case.call_and_validate(base_url=served.url)
