"""Finding the deployment a request names."""

from __future__ import annotations

import uuid

from sqlalchemy.orm import Session

from roadlink.db import repository
from roadlink.db.models import Deployment
from roadlink.services.problems import ServiceProblem


def require_deployment(session: Session, deployment_id: uuid.UUID) -> Deployment:
    """The deployment, or 404 naming it."""
    deployment = repository.get_deployment(session, deployment_id=deployment_id)
    if deployment is None:
        raise ServiceProblem(404, f"there is no deployment {deployment_id}")
    return deployment
