"""The committed contract, openapi/openapi.json, is what the app serves."""

from __future__ import annotations

import json
from pathlib import Path

from roadlink.api.app import create_app, openapi_json
from roadlink.settings import Settings

SPEC = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"
REGENERATE = "run `roadlink openapi` (writes openapi/openapi.json) and commit the result"


def test_the_committed_spec_matches_the_app() -> None:
    served = openapi_json(create_app(Settings(database_url="sqlite://")))
    assert SPEC.is_file(), f"openapi/openapi.json is missing: {REGENERATE}"
    assert json.loads(SPEC.read_text()) == json.loads(served), (
        f"the API drifted from openapi/openapi.json: {REGENERATE}"
    )


def test_every_operation_is_tagged_named_and_documented() -> None:
    spec = json.loads(SPEC.read_text())
    for path, operations in spec["paths"].items():
        for method, operation in operations.items():
            where = f"{method.upper()} {path}"
            tag = operation["tags"][0]
            assert operation["operationId"].startswith(f"{tag}-"), where
            assert operation.get("summary") and operation.get("description"), where
            status, ok = next((s, r) for s, r in operation["responses"].items() if s[0] == "2")
            # 204 No Content (a delete) is the one success without a body.
            assert status == "204" or ok.get("content"), f"{where} documents no response body"
            for status, response in operation["responses"].items():
                if status.startswith(("4", "5")):
                    assert "application/problem+json" in response["content"], (where, status)
    # Every schema of a JSON body or response carries an example.
    schemas = spec["components"]["schemas"]
    for name in (
        "DeploymentCreate",
        "DeploymentRead",
        "BatchCreate",
        "BatchRead",
        "JobCreate",
        "JobRead",
        "AssociationResultRead",
        "AssociatorRead",
        "SimulationCreate",
        "ProblemDetail",
    ):
        assert schemas[name].get("examples"), name
