"""A succeeded job's result and what is derived from it: targets, positions, trajectories,
the link to its page."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from pydantic.json_schema import SkipJsonSchema

from roadlink.api.schemas.examples import EXAMPLE_ID


class TargetDetectionRead(BaseModel):
    """One detection of the result; with `lane`, `length` and `vehicle_class` when the job's
    detections report them (the example)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "detection_id": "d2",
                    "sensor_id": "S2",
                    "position": 100.0,
                    "velocity": 30.5,
                    "timestamp": 15.7,
                    "lane": None,
                    "length": 4.6,
                    "vehicle_class": "car",
                    "link_confidence": 0.98,
                }
            ]
        }
    )

    detection_id: str
    sensor_id: str
    position: float
    velocity: float
    timestamp: float
    # Absent when the input reported the feature for no detection (the result is then as it was
    # before features existed); null where it reported it for others but not this one.
    lane: int | None = Field(
        default=None,
        ge=0,
        description="The lane its detector reported (0 = rightmost). Present only when some "
        "detection of the job reported a lane; null where this one did not.",
    )
    length: float | None = Field(
        default=None,
        gt=0,
        description="The vehicle length its detector measured (the deployment's position "
        "unit). Present only when some detection of the job reported a length; null where "
        "this one did not.",
    )
    vehicle_class: str | None = Field(
        default=None,
        max_length=32,
        description="The vehicle class its detector reported. Present only when some "
        "detection of the job reported a class; null where this one did not.",
    )
    # Absent, never null, where there is no link: so the schema has no null.
    link_confidence: float | SkipJsonSchema[None] = Field(
        default=None,
        ge=0,
        le=1,
        description="The approximate probability that the link from the target's previous "
        "detection to this one is right (docs/assignment.md, Confidence). Absent on a target's "
        "first detection, on a sensor's second report of one passage (a copy beside its twin, "
        "linked by nothing), on unassigned ones, and from associators that group points rather "
        "than link them (K-means, the SVMs).",
    )


class TargetRead(BaseModel):
    target: str = Field(description="T1, T2, ... in the order targets pass the reference sensor.")
    confidence: float | SkipJsonSchema[None] = Field(
        default=None,
        ge=0,
        le=1,
        description="The approximate probability that every link of the target is right: the "
        "product of its detections' `link_confidence` (1 for a target of one detection). Absent "
        "from associators that group points rather than link them.",
    )
    length: float | None = Field(
        default=None,
        gt=0,
        description="The median of its detections' measured lengths (one faulty reading does "
        "not move it). Present only when some detection of the job reported a length; null "
        "when none of this target's did.",
    )
    vehicle_class: str | None = Field(
        default=None,
        max_length=32,
        description="The class its detections report most often (a tie goes to the class "
        "reported first along the road). Present only when some detection of the job reported "
        "a class; null when none of this target's did.",
    )
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
    # Absent, never null or empty, where the associator found nothing wrong.
    warnings: list[str] | SkipJsonSchema[None] = Field(
        default=None,
        description="What the associator found wrong with the detectors, one sentence each, "
        "for whoever keeps them: a sensor whose clock is off (its times were set right for the "
        "association), one whose speeds read some factor off its neighbours' (a calibration, "
        "or km/h among sensors in m/s). Absent where there is nothing to say.",
    )
    n_detections: int
    n_targets: int
    targets: list[TargetRead]
    unassigned: list[TargetDetectionRead] = Field(description="Detections of no target.")
    metrics: MetricsRead | None = Field(description="Null when no detection is labelled.")


class VehicleFeaturesRead(BaseModel):
    """What a target's detections say of the vehicle, as the result's target gives it."""

    length: float | None = Field(
        default=None,
        gt=0,
        description="The median of its detections' measured lengths. Present only when some "
        "detection of the job reported a length; null when none of this target's did.",
    )
    vehicle_class: str | None = Field(
        default=None,
        max_length=32,
        description="The class its detections report most often. Present only when some "
        "detection of the job reported a class; null when none of this target's did.",
    )


class TargetPositionRead(VehicleFeaturesRead):
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


class TargetTrajectoryRead(VehicleFeaturesRead):
    """One target's passes, its travel times and mean speeds between sensors, and its track
    sampled from its first to its last pass; where detectors report them, the vehicle's length
    and class."""

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
