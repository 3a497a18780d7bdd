"""The API's request and response bodies, a module per domain; every name is importable from
here, as `roadlink.api.schemas.X`."""

from __future__ import annotations

from roadlink.api.schemas.batches import (
    AssociateRequest,
    BatchCreate,
    BatchRead,
    DetectionIn,
    batch_read,
)
from roadlink.api.schemas.catalogue import AssociatorRead, SimulationCreate, SimulationOverrides
from roadlink.api.schemas.deployments import DeploymentCreate, DeploymentRead, SensorSpec
from roadlink.api.schemas.examples import EXAMPLE_ID
from roadlink.api.schemas.health import HealthRead, ReadinessRead
from roadlink.api.schemas.jobs import JobCreate, JobRead
from roadlink.api.schemas.pages import (
    BatchPage,
    BatchSummary,
    DeliveryPage,
    DeploymentPage,
    JobPage,
    WebhookPage,
)
from roadlink.api.schemas.results import (
    AssociationResultRead,
    MetricsRead,
    PageLinkRead,
    PositionsRead,
    SegmentRead,
    SensorPassRead,
    TargetDetectionRead,
    TargetPositionRead,
    TargetRead,
    TargetTrajectoryRead,
    TrackPointRead,
)
from roadlink.api.schemas.webhooks import (
    DeliveryRead,
    WebhookCreate,
    WebhookCreated,
    WebhookRead,
)

__all__ = [
    "EXAMPLE_ID",
    "AssociateRequest",
    "AssociationResultRead",
    "AssociatorRead",
    "BatchCreate",
    "BatchPage",
    "BatchRead",
    "BatchSummary",
    "DeliveryPage",
    "DeliveryRead",
    "DeploymentCreate",
    "DeploymentPage",
    "DeploymentRead",
    "DetectionIn",
    "HealthRead",
    "JobCreate",
    "JobPage",
    "JobRead",
    "MetricsRead",
    "PageLinkRead",
    "PositionsRead",
    "ReadinessRead",
    "SegmentRead",
    "SensorPassRead",
    "SensorSpec",
    "SimulationCreate",
    "SimulationOverrides",
    "TargetDetectionRead",
    "TargetPositionRead",
    "TargetRead",
    "TargetTrajectoryRead",
    "TrackPointRead",
    "WebhookCreate",
    "WebhookCreated",
    "WebhookPage",
    "WebhookRead",
    "batch_read",
]
