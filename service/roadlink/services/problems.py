"""Problems with a request that the services find (no such deployment, a reused
Idempotency-Key, a selection without detections): raised here, answered by the API as problem
details (application/problem+json) in one place, `api/errors.py`."""

from __future__ import annotations

from collections.abc import Sequence

from pydantic import BaseModel, Field


class ProblemItem(BaseModel):
    """One thing wrong with the request: where it is and what is wrong."""

    row: int | None = Field(
        default=None, description="1-based data row (detection) at fault, when one is."
    )
    field: str | None = Field(default=None, description="Field or column at fault, when one is.")
    pointer: str | None = Field(
        default=None, description="JSON Pointer (RFC 6901) into the request body, when JSON."
    )
    message: str = Field(description="What is wrong, in words a person can act on.")


class ServiceProblem(Exception):
    """A request the service will not carry out: the status that classifies it (the HTTP status
    code the API answers with, so that the two cannot drift apart), what is wrong, and where."""

    def __init__(self, status: int, detail: str, *, errors: Sequence[ProblemItem] = ()) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.errors = list(errors)
