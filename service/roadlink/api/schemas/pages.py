"""Pages of the lists (api/pagination.py): the items, and the cursor and link of the next page."""

from __future__ import annotations

from pydantic import BaseModel, Field

from roadlink.api.schemas.batches import BatchRead
from roadlink.api.schemas.deployments import DeploymentRead
from roadlink.api.schemas.jobs import JobRead
from roadlink.api.schemas.webhooks import DeliveryRead, WebhookRead

NEXT_DESCRIPTION = (
    "The next page's link: this request's path and query with the next cursor. Null on the "
    "last page."
)
NEXT_CURSOR_DESCRIPTION = "Pass as `cursor` for the next page (opaque). Null on the last page."


class BatchSummary(BatchRead):
    """A batch in a deployment's list: the stored batch, its job, and the sensors it reports."""

    sensors: list[str] = Field(description="The sensor ids its detections name, sorted.")


class DeploymentPage(BaseModel):
    """A page of deployments, oldest first."""

    items: list[DeploymentRead]
    next_cursor: str | None = Field(description=NEXT_CURSOR_DESCRIPTION)
    next: str | None = Field(description=NEXT_DESCRIPTION)


class BatchPage(BaseModel):
    """A page of a deployment's batches, newest first."""

    items: list[BatchSummary]
    next_cursor: str | None = Field(description=NEXT_CURSOR_DESCRIPTION)
    next: str | None = Field(description=NEXT_DESCRIPTION)


class JobPage(BaseModel):
    """A page of jobs, newest first."""

    items: list[JobRead]
    next_cursor: str | None = Field(description=NEXT_CURSOR_DESCRIPTION)
    next: str | None = Field(description=NEXT_DESCRIPTION)


class WebhookPage(BaseModel):
    """A page of a deployment's webhooks, oldest first."""

    items: list[WebhookRead]
    next_cursor: str | None = Field(description=NEXT_CURSOR_DESCRIPTION)
    next: str | None = Field(description=NEXT_DESCRIPTION)


class DeliveryPage(BaseModel):
    """A page of a webhook's delivery log, newest first."""

    items: list[DeliveryRead]
    next_cursor: str | None = Field(description=NEXT_CURSOR_DESCRIPTION)
    next: str | None = Field(description=NEXT_DESCRIPTION)
