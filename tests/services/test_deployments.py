"""Finding the deployment a request names (`roadlink.services.deployments`)."""

from __future__ import annotations

import uuid

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from roadlink.db import repository
from roadlink.services.deployments import require_deployment
from roadlink.services.problems import ServiceProblem


def test_a_deployment_is_found_or_named_in_a_404(engine: Engine) -> None:
    missing = uuid.uuid4()
    with Session(engine) as session, session.begin():
        deployment = repository.create_deployment(session, name="road", sensors=None)
        assert require_deployment(session, deployment.id) is deployment
        with pytest.raises(ServiceProblem) as raised:
            require_deployment(session, missing)
    assert raised.value.status == 404 and str(missing) in raised.value.detail
