"""A deployment's live association and its feed of vehicles (issue 18)."""

from __future__ import annotations

import uuid
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from roadlink.association.associators import DEFAULT_ASSOCIATOR

DEFAULT_LATENESS_SECONDS = 15.0


class LiveStart(BaseModel):
    """How to associate the deployment's detections as they arrive."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"associator": "assignment", "lateness": 15.0}]},
    )

    associator: str = Field(
        default=DEFAULT_ASSOCIATOR, description="An associator of GET /v1/associators."
    )
    params: dict[str, Any] = Field(default_factory=dict, description="Its parameters.")
    lateness: float = Field(
        default=DEFAULT_LATENESS_SECONDS,
        ge=0,
        le=1e9,
        allow_inf_nan=False,
        description="How far behind the data clock a detection may arrive and still join its "
        "vehicle (timestamp units): how long a vehicle stays open after its predicted passage "
        "of the last sensor. At least the batch period of the slowest gateway.",
    )


class LiveStatusRead(BaseModel):
    """Where a deployment's live association stands."""

    model_config = ConfigDict(from_attributes=True)

    deployment_id: uuid.UUID
    state: Literal["running", "stopped"]
    associator: str
    params: dict[str, Any]
    lateness: float
    data_clock: float | None = Field(description="The newest detection timestamp received.")
    step_clock: float | None = Field(description="The data clock its last step ran at.")
    lag: float | None = Field(description="data_clock - step_clock: data not yet associated.")
    pending: bool = Field(description="Whether data or a flush is waiting for a step.")
    open_tracks: int = Field(description="Vehicles still open (unpublished) after the last step.")
    open_detections: int = Field(description="Detections not yet settled after the last step.")
    vehicles_published: int
    late_detections: int = Field(
        description="Detections that arrived after every vehicle they could join was final: "
        "stored (offline jobs see them) but in no live vehicle."
    )


class LiveDetectionRead(BaseModel):
    """A detection of a published vehicle, as its gateway sent it, with its batch."""

    model_config = ConfigDict(extra="allow")

    detection_id: str
    batch_id: uuid.UUID
    sensor_id: str
    position: float
    velocity: float
    timestamp: float
    target: str | None = Field(default=None, description="The true label, when one was sent.")
    lane: int | None = None
    length: float | None = None
    vehicle_class: str | None = None


class VehicleRead(BaseModel):
    """A vehicle the live association published."""

    vehicle_id: str = Field(description="Stable and unique within the deployment: V1, V2, ...")
    revision: int = Field(description="1: vehicles are published once, final.")
    final: bool = Field(description="True: no detection still to come can join it.")
    confidence: float | None = Field(
        description="The approximate probability that the vehicle is right (from an "
        "associator that builds targets from links, such as assignment)."
    )
    first_timestamp: float
    last_timestamp: float
    cursor: str = Field(description="Its place in the feed: ?after= or Last-Event-ID.")
    detections: list[LiveDetectionRead] = Field(description="In time order.")


class VehiclePage(BaseModel):
    """A page of the feed, in publication order. Shaped as the lists' pages are, but a feed has
    no last page: `next` is never null, and on an empty page it asks again from where this one
    started (with `wait`, a long poll)."""

    items: list[VehicleRead]
    next_cursor: str = Field(description="Pass as `after` for the next page (opaque).")
    next: str = Field(
        description="The next page's link: this request's path and query with `after` set to "
        "`next_cursor`. Never null: follow it (with `wait`) for the vehicles still to come."
    )
