"""Request and response bodies: `XCreate` in, `XRead` out."""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator
from pydantic.json_schema import SkipJsonSchema

from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.db.models import JobState
from roadlink.simulation import PRESETS, SimulationConfig

EXAMPLE_ID = "0d5f8a4e-0b8e-4c39-9d47-5a1b2c3d4e5f"


class SensorSpec(BaseModel):
    """A sensor of a deployment: its id and where it is along the road."""

    model_config = ConfigDict(extra="forbid")

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


class DetectionIn(BaseModel):
    """One sensor report (the same fields as the detection CSV's columns)."""

    position: float = Field(description="Sensor position along the road (metres).")
    velocity: float = Field(gt=0, description="Measured velocity (metres per second, > 0).")
    timestamp: float = Field(description="Time of the detection (seconds).")
    sensor_id: str | None = Field(
        default=None, description="Sensor id (named by position if absent)."
    )
    detection_id: str | None = Field(
        default=None, description="Unique id within the batch (d1, d2, ... if absent)."
    )
    target: str | None = Field(
        default=None,
        description="True target label, for scoring and supervised associators; 'clutter' marks "
        "a false alarm; absent = unlabelled.",
    )


class AssociateRequest(BaseModel):
    """Which associator to run, with which parameters."""

    model_config = ConfigDict(extra="forbid")

    associator: str = Field(
        default=DEFAULT_ASSOCIATOR, description="Name from GET /v1/associators."
    )
    params: dict[str, Any] = Field(
        default_factory=dict, description="The associator's parameters (its JSON Schema)."
    )


class BatchCreate(BaseModel):
    """A batch of detections, optionally with a job to associate them at once."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "detections": [
                        {"position": 0.0, "velocity": 41.2, "timestamp": 3.1, "target": "A1"},
                        {"position": 100.0, "velocity": 40.7, "timestamp": 5.5, "target": "A1"},
                    ],
                    "associate": {"associator": DEFAULT_ASSOCIATOR, "params": {}},
                }
            ]
        },
    )

    detections: list[DetectionIn] = Field(description="The detections, in any order.")
    associate: AssociateRequest | None = Field(
        default=None, description="Enqueue a job for this batch in the same transaction."
    )


class JobRead(BaseModel):
    """A job: what it covers and where it stands."""

    model_config = ConfigDict(
        from_attributes=True,
        json_schema_extra={
            "examples": [
                {
                    "id": EXAMPLE_ID,
                    "deployment_id": EXAMPLE_ID,
                    "selection": {"batch_ids": [EXAMPLE_ID]},
                    "associator": DEFAULT_ASSOCIATOR,
                    "params": {},
                    "state": "running",
                    "progress": 0.4,
                    "attempts": 1,
                    "max_attempts": 3,
                    "error": None,
                    "n_detections": None,
                    "created_at": "2026-01-01T12:00:00Z",
                    "started_at": "2026-01-01T12:00:01Z",
                    "finished_at": None,
                    "duration_seconds": None,
                }
            ]
        },
    )

    id: uuid.UUID
    deployment_id: uuid.UUID
    selection: dict[str, Any] = Field(
        description="{batch_ids: [...]} or {start, end}: the time window [start, end)."
    )
    associator: str
    params: dict[str, Any]
    state: JobState
    progress: float = Field(description="Share of the work done, 0 to 1.")
    attempts: int = Field(description="Runs started so far.")
    max_attempts: int
    error: str | None = Field(description="Why the last run failed, if one did.")
    n_detections: int | None = Field(description="Detections covered (known once it ran).")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    duration_seconds: float | None = Field(description="Run time of the successful run.")


class BatchRead(BaseModel):
    """A stored batch, and the job enqueued with it when association was asked for."""

    model_config = ConfigDict(
        from_attributes=True,
        json_schema_extra={
            "examples": [
                {
                    "id": EXAMPLE_ID,
                    "deployment_id": EXAMPLE_ID,
                    "n_detections": 100,
                    "n_labelled": 100,
                    "first_timestamp": 1.2,
                    "last_timestamp": 58.3,
                    "source": "json",
                    "created_at": "2026-01-01T12:00:00Z",
                    "job": None,
                }
            ]
        },
    )

    id: uuid.UUID
    deployment_id: uuid.UUID
    n_detections: int
    n_labelled: int = Field(description="Detections with a true label (scored when associated).")
    first_timestamp: float
    last_timestamp: float
    source: Literal["json", "csv", "simulation"]
    created_at: datetime
    job: JobRead | None = Field(default=None, description="The job enqueued with the batch.")


class JobCreate(BaseModel):
    """What to associate: one batch, several, or a deployment's time window [start, end)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"batch_id": EXAMPLE_ID, "associator": DEFAULT_ASSOCIATOR},
                {"deployment_id": EXAMPLE_ID, "start": 0.0, "end": 60.0, "associator": "kmeans"},
            ]
        },
    )

    batch_id: uuid.UUID | None = Field(default=None, description="One batch.")
    batch_ids: list[uuid.UUID] | None = Field(
        default=None, min_length=1, description="Several batches of one deployment."
    )
    deployment_id: uuid.UUID | None = Field(
        default=None, description="A deployment: its detections with start <= timestamp < end."
    )
    start: float | None = Field(default=None, allow_inf_nan=False, description="Window start.")
    end: float | None = Field(default=None, allow_inf_nan=False, description="Window end.")
    associator: str = Field(
        default=DEFAULT_ASSOCIATOR, description="Name from GET /v1/associators."
    )
    params: dict[str, Any] = Field(default_factory=dict, description="The associator's parameters.")

    @model_validator(mode="after")
    def _one_selection(self) -> JobCreate:
        given = [
            name
            for name in ("batch_id", "batch_ids", "deployment_id")
            if getattr(self, name) is not None
        ]
        if len(given) != 1:
            raise ValueError("give exactly one of batch_id, batch_ids, deployment_id")
        if (self.start is not None or self.end is not None) and self.deployment_id is None:
            raise ValueError("a time window (start, end) needs deployment_id")
        if self.start is not None and self.end is not None and self.start >= self.end:
            raise ValueError("the window [start, end) is empty: start must be before end")
        return self


class TargetDetectionRead(BaseModel):
    detection_id: str
    sensor_id: str
    position: float
    velocity: float
    timestamp: float


class TargetRead(BaseModel):
    target: str = Field(description="T1, T2, ... in the order targets pass the reference sensor.")
    detections: list[TargetDetectionRead] = Field(description="Its detections, by position.")


class MetricsRead(BaseModel):
    accuracy: float = Field(description="The paper's accuracy (Hungarian matching).")
    pairwise_precision: float
    pairwise_recall: float
    pairwise_f1: float
    ari: float = Field(description="Adjusted Rand index.")
    complete_targets: float = Field(description="Share of targets grouped exactly right.")


class AssociationResultRead(BaseModel):
    """The association result (the same JSON as `roadlink associate --json`)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "associator": "kmeans++",
                    "params": {},
                    "n_detections": 3,
                    "n_targets": 1,
                    "targets": [
                        {
                            "target": "T1",
                            "detections": [
                                {
                                    "detection_id": "d1",
                                    "sensor_id": "S1",
                                    "position": 0.0,
                                    "velocity": 30.2,
                                    "timestamp": 12.4,
                                },
                                {
                                    "detection_id": "d2",
                                    "sensor_id": "S2",
                                    "position": 100.0,
                                    "velocity": 30.5,
                                    "timestamp": 15.7,
                                },
                            ],
                        }
                    ],
                    "unassigned": [
                        {
                            "detection_id": "d3",
                            "sensor_id": "S2",
                            "position": 100.0,
                            "velocity": 51.0,
                            "timestamp": 7.0,
                        }
                    ],
                    "metrics": None,
                }
            ]
        }
    )

    associator: str
    params: dict[str, Any] = Field(description="The parameters asked for, defaults filled in.")
    # Absent, never null, from an associator that adapts nothing: so the schema has no null.
    effective_params: dict[str, Any] | SkipJsonSchema[None] = Field(
        default=None,
        description="The parameters the associator ran with, from an associator that adapts "
        "the ones asked for to the detections; absent from one that runs with them as given. "
        "`assignment` holds its parameters in time units (duplicate_window, timestamp_noise) "
        "to shares of a typical travel time between neighbouring sensors (docs/assignment.md).",
    )
    n_detections: int
    n_targets: int
    targets: list[TargetRead]
    unassigned: list[TargetDetectionRead] = Field(description="Detections of no target.")
    metrics: MetricsRead | None = Field(description="Null when no detection is labelled.")


class TargetPositionRead(BaseModel):
    target: str = Field(description="The target, named as in the result (T1, T2, ...).")
    position: float = Field(description="Estimated position along the road.")
    velocity: float = Field(description="Estimated velocity.")


class PositionsRead(BaseModel):
    """Every target on the observed road at one time, by cubic Hermite interpolation between
    its sensor passes."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "time": 20.0,
                    "targets": [
                        {"target": "T1", "position": 512.3, "velocity": 30.4},
                        {"target": "T2", "position": 148.9, "velocity": 27.1},
                    ],
                }
            ]
        }
    )

    time: float = Field(description="The time asked for.")
    targets: list[TargetPositionRead] = Field(
        description="Targets between their first and last pass at that time, in target order; "
        "the others are off the observed road."
    )


class SensorPassRead(BaseModel):
    sensor_id: str
    position: float
    timestamp: float
    velocity: float
    detection_ids: list[str] = Field(
        description="The detection, or several of one sensor merged into their mean."
    )


class SegmentRead(BaseModel):
    from_sensor: str
    to_sensor: str
    from_position: float
    to_position: float
    departure: float = Field(description="Time of the pass at from_sensor.")
    arrival: float = Field(description="Time of the pass at to_sensor.")
    travel_time: float
    distance: float
    mean_speed: float = Field(
        description="distance / travel_time; negative when the target runs against the road "
        "(a sign of wrongly grouped detections)."
    )


class TrackPointRead(BaseModel):
    time: float
    position: float
    velocity: float


class TargetTrajectoryRead(BaseModel):
    """One target's passes, its travel times and mean speeds between sensors, and its track
    sampled from its first to its last pass."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "target": "T1",
                    "start": 12.4,
                    "end": 15.7,
                    "monotone": True,
                    "passes": [
                        {
                            "sensor_id": "S1",
                            "position": 0.0,
                            "timestamp": 12.4,
                            "velocity": 30.2,
                            "detection_ids": ["d1"],
                        },
                        {
                            "sensor_id": "S2",
                            "position": 100.0,
                            "timestamp": 15.7,
                            "velocity": 30.5,
                            "detection_ids": ["d2"],
                        },
                    ],
                    "segments": [
                        {
                            "from_sensor": "S1",
                            "to_sensor": "S2",
                            "from_position": 0.0,
                            "to_position": 100.0,
                            "departure": 12.4,
                            "arrival": 15.7,
                            "travel_time": 3.3,
                            "distance": 100.0,
                            "mean_speed": 30.3,
                        }
                    ],
                    "samples": [
                        {"time": 12.4, "position": 0.0, "velocity": 30.2},
                        {"time": 14.4, "position": 60.9, "velocity": 30.7},
                        {"time": 15.7, "position": 100.0, "velocity": 30.5},
                    ],
                    "dropped_detection_ids": [],
                }
            ]
        }
    )

    target: str
    start: float = Field(description="Time of its first pass.")
    end: float = Field(description="Time of its last pass.")
    monotone: bool = Field(
        description="False when it goes backwards along the road between two passes: its "
        "detections were grouped wrongly, and its positions are not to be trusted."
    )
    passes: list[SensorPassRead] = Field(description="One per sensor, in time order.")
    segments: list[SegmentRead] = Field(description="Between consecutive passes.")
    samples: list[TrackPointRead] = Field(description="The track, every `step` and at the end.")
    dropped_detection_ids: list[str] = Field(
        description="Detections left out: passes at other sensors at the very same time, which "
        "no moving target can make."
    )


class PageLinkRead(BaseModel):
    """A link to a job's page that opens in a browser without an API key."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "url": f"/jobs/{EXAMPLE_ID}?token=d74a2839.1767272400.Xq3...",
                    "expires_at": "2026-01-01T13:00:00Z",
                }
            ]
        }
    )

    url: str = Field(
        description="The page, with a token that lets whoever holds the link see this one job's "
        "page until it expires or the key that made it is revoked. Absolute under the "
        "configured ROADLINK_PUBLIC_URL; else a path on the server that was asked."
    )
    expires_at: datetime | None = Field(
        description="When the link stops working; null when authentication is disabled (the "
        "page needs no token)."
    )


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


class HealthRead(BaseModel):
    status: Literal["ok"] = "ok"


class ReadinessRead(BaseModel):
    status: Literal["ready"] = "ready"
    database: str = Field(description="The database dialect in use.")
    revision: str = Field(description="The schema revision (the newest migration).")
