"""API keys in the database: only a hash is kept, keys are found by their public prefix and
checked in full, revoked keys are refused (`roadlink.db.apikeys`)."""

from __future__ import annotations

import uuid

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from roadlink.db.apikeys import (
    authenticate_api_key,
    create_api_key,
    find_api_key,
    has_admin_key,
    key_prefix,
    key_sha256,
    list_api_keys,
    revoke_api_key,
)
from roadlink.db.models import ApiKeyScope


def test_a_key_is_stored_as_its_hash_and_found_by_its_prefix(engine: Engine) -> None:
    with Session(engine) as session, session.begin():
        issued = create_api_key(session, scope=ApiKeyScope.READ, name="reader")
        assert issued.row.secret_sha256 == key_sha256(issued.key) != issued.key
        assert key_prefix(issued.key) == issued.row.prefix
        assert authenticate_api_key(session, key=issued.key) is issued.row
        assert find_api_key(session, reference=issued.row.prefix) is issued.row
        assert find_api_key(session, reference=str(issued.row.id)) is issued.row


@pytest.mark.parametrize("key", ["", "rl_", "rl_short_secret", "xx_" + "0" * 16 + "_s"])
def test_what_is_not_one_of_our_keys_has_no_prefix(key: str) -> None:
    assert key_prefix(key) is None


def test_a_wrong_secret_or_a_revoked_key_does_not_authenticate(engine: Engine) -> None:
    with Session(engine) as session, session.begin():
        issued = create_api_key(session, scope=ApiKeyScope.ADMIN)
        assert authenticate_api_key(session, key=issued.key + "x") is None
        assert has_admin_key(session)
        assert revoke_api_key(session, key_id=issued.row.id)
        assert not revoke_api_key(session, key_id=issued.row.id), "revoked already"
        assert authenticate_api_key(session, key=issued.key) is None
        assert not has_admin_key(session)
        assert list_api_keys(session, include_revoked=False) == []
        assert list_api_keys(session) == [issued.row]


def test_only_ingest_keys_name_deployments(engine: Engine) -> None:
    deployment = uuid.uuid4()
    with Session(engine) as session, session.begin():
        with pytest.raises(ValueError, match="at least one deployment"):
            create_api_key(session, scope=ApiKeyScope.INGEST)
        with pytest.raises(ValueError, match="only ingest keys"):
            create_api_key(session, scope=ApiKeyScope.READ, deployment_ids=[deployment])
        issued = create_api_key(
            session, scope=ApiKeyScope.INGEST, deployment_ids=[deployment, deployment]
        )
        assert issued.row.deployment_ids == [str(deployment)]
