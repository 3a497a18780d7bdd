"""What the service offers besides jobs: its associators and its simulations."""

from __future__ import annotations

import uuid
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model

from roadlink.api.schemas.batches import AssociateRequest
from roadlink.api.schemas.examples import EXAMPLE_ID
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.simulation import PRESETS, SimulationConfig


class AssociatorRead(BaseModel):
    """An associator the service can run."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "name": "kmeans++",
                    "description": "The paper's K-means++ ...",
                    "needs_labels": False,
                    "default": True,
                    "parameters": {"type": "object", "properties": {}},
                }
            ]
        }
    )

    name: str
    description: str
    needs_labels: bool = Field(description="Supervised: trains on the labelled detections.")
    default: bool = Field(description="Used when a job names no associator.")
    parameters: dict[str, Any] = Field(description="JSON Schema of its parameters.")


# Every SimulationConfig setting, optional: what is not given comes from the preset.
SimulationOverrides: type[BaseModel] = create_model(  # type: ignore[call-overload]
    "SimulationOverrides",
    __config__=ConfigDict(extra="forbid"),
    __doc__="Simulation settings to change from the preset (see SimulationConfig).",
    **{
        name: (
            field.annotation | None,  # type: ignore[operator]
            Field(default=None, description=field.description),
        )
        for name, field in SimulationConfig.model_fields.items()
    },
)


class SimulationCreate(BaseModel):
    """Generate a labelled batch with the paper's Algorithm 1 into a deployment."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "deployment_id": EXAMPLE_ID,
                    "preset": "large",
                    "seed": 7,
                    "config": {"n_targets": 10},
                    "associate": {"associator": DEFAULT_ASSOCIATOR},
                }
            ]
        },
    )

    deployment_id: uuid.UUID
    preset: Literal[tuple(PRESETS)] = Field(  # type: ignore[valid-type]
        default="large", description="The paper's large / medium / small tables, or congested."
    )
    seed: int = Field(default=0, ge=0, description="Same seed, same detections.")
    config: SimulationOverrides = Field(  # type: ignore[valid-type]
        default_factory=SimulationOverrides,
        description="Settings to change from the preset. When the deployment declares sensors "
        "and no sensor_positions are given, its sensors are used.",
    )
    associate: AssociateRequest | None = Field(
        default=None, description="Enqueue a job for the batch in the same transaction."
    )
