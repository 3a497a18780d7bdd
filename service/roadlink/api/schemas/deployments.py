"""Deployments: a stretch of road and its declared sensors."""

from __future__ import annotations

import uuid
from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field, model_validator

from roadlink.api.schemas.examples import EXAMPLE_ID


class SensorSpec(BaseModel):
    """A sensor of a deployment: its id and where it is along the road."""

    # from_attributes: a deployment read back holds its sensors as `db.json_columns.Sensor`s.
    model_config = ConfigDict(extra="forbid", from_attributes=True)

    sensor_id: str = Field(min_length=1, max_length=200, description="The id detections use.")
    position: float = Field(
        ge=-1e12, le=1e12, allow_inf_nan=False, description="Position along the road (metres)."
    )


class DeploymentCreate(BaseModel):
    """A stretch of road; declaring its sensors lets the service reject unknown ones."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "name": "A9 northbound km 12-13",
                    "sensors": [
                        {"sensor_id": "S1", "position": 0.0},
                        {"sensor_id": "S2", "position": 100.0},
                    ],
                }
            ]
        },
    )

    name: str = Field(min_length=1, max_length=200, description="A name people recognise.")
    sensors: list[SensorSpec] | None = Field(
        default=None,
        min_length=2,
        description="The sensors, if declared: detections must then name one of them.",
    )

    @model_validator(mode="after")
    def _distinct_sensors(self) -> DeploymentCreate:
        if self.sensors:
            ids = [s.sensor_id for s in self.sensors]
            positions = [s.position for s in self.sensors]
            if len(set(ids)) != len(ids):
                raise ValueError("sensor ids must be distinct")
            if len(set(positions)) != len(positions):
                raise ValueError("sensor positions must be distinct")
        return self


class DeploymentRead(BaseModel):
    """A deployment."""

    model_config = ConfigDict(
        from_attributes=True,
        json_schema_extra={
            "examples": [
                {
                    "id": EXAMPLE_ID,
                    "name": "A9 northbound km 12-13",
                    "sensors": [
                        {"sensor_id": "S1", "position": 0.0},
                        {"sensor_id": "S2", "position": 100.0},
                    ],
                    "created_at": "2026-01-01T12:00:00Z",
                }
            ]
        },
    )

    id: uuid.UUID
    name: str
    sensors: list[SensorSpec] | None
    created_at: datetime
