"""`GET /v1/associators` (`api/routers/associators.py`): the catalogue of associators."""

from __future__ import annotations

from fastapi.testclient import TestClient

from roadlink.association.associators import ASSOCIATORS, DEFAULT_ASSOCIATOR


def test_associators_list_every_registered_one_with_its_parameters(client: TestClient) -> None:
    listed = {a["name"]: a for a in client.get("/v1/associators").json()}
    assert set(listed) == set(ASSOCIATORS)
    assert [n for n, a in listed.items() if a["default"]] == [DEFAULT_ASSOCIATOR]
    for name, cls in ASSOCIATORS.items():
        assert listed[name]["parameters"] == cls.parameters_schema()
        assert listed[name]["needs_labels"] == cls.needs_labels
