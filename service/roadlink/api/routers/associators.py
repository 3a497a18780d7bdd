"""The associators a job can use."""

from __future__ import annotations

from fastapi import APIRouter

from roadlink.api.schemas import AssociatorRead
from roadlink.association.associators import ASSOCIATORS, DEFAULT_ASSOCIATOR

router = APIRouter(prefix="/v1/associators", tags=["associators"])


@router.get("", name="list", response_model=list[AssociatorRead], summary="List associators")
def list_associators() -> list[AssociatorRead]:
    """Every associator: name, description, whether it needs labels, its parameters' schema."""
    return [
        AssociatorRead(
            name=name,
            description=cls.description,
            needs_labels=cls.needs_labels,
            default=name == DEFAULT_ASSOCIATOR,
            parameters=cls.parameters_schema(),
        )
        for name, cls in ASSOCIATORS.items()
    ]
