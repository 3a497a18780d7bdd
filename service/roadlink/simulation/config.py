"""Simulation settings: the paper's Tables I-III as presets, plus the faults it leaves for later."""

from __future__ import annotations

from typing import Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

from roadlink.association.feature_columns import MAX_LANE
from roadlink.simulation.faults import DetectorFaults


class SlowZone(BaseModel):
    """A stretch of road where every target drives slower, as in congestion or roadworks."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    start: float = Field(description="Where the zone begins (same unit as positions).")
    end: float = Field(description="Where the zone ends.")
    speed_factor: float = Field(
        gt=0, le=1, description="Speed inside the zone as a share of the target's own speed."
    )

    @model_validator(mode="after")
    def _ordered(self) -> SlowZone:
        if self.end <= self.start:
            raise ValueError("slow zone end must be beyond its start")
        return self


class Traffic(BaseModel):
    """The traffic Algorithm 1 simulates: targets, sensors, speeds and when targets enter."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_targets: int = Field(default=10, ge=1, le=1_000_000, description="Number of targets N_A.")
    sensor_positions: list[float] = Field(
        default=[100.0 * i for i in range(10)],
        min_length=2,
        description="Sensor positions R (the paper: a sensor every 100 m from 0).",
    )
    velocity_range: tuple[float, float] = Field(
        default=(30.0, 80.0), description="Initial velocity v0 ~ U[min, max] (m/s)."
    )
    start_time_range: tuple[float, float] = Field(
        default=(1.0, 30.0), description="Time t0 ~ U[min, max] at which a target enters the road."
    )
    velocity_model: Literal["ou", "constant"] = Field(
        default="ou",
        description="The paper's unspecified profile g(v0, t0): 'ou' lets velocity fluctuate "
        "around v0 (Ornstein-Uhlenbeck process); 'constant' keeps v0.",
    )
    velocity_fluctuation: float = Field(
        default=0.05,
        ge=0,
        le=1,
        description="Stationary standard deviation of the OU velocity, as a share of v0.",
    )
    velocity_correlation_time: float = Field(
        default=10.0, gt=0, description="OU correlation time (s): how long a speed change lasts."
    )
    time_step: float = Field(default=0.05, gt=0, le=10, description="Integration step (s).")
    slow_zone: SlowZone | None = Field(default=None, description="Congested stretch, if any.")

    @model_validator(mode="after")
    def _ranges(self) -> Traffic:
        lo, hi = self.velocity_range
        if not 0 < lo <= hi:
            raise ValueError("velocity_range must satisfy 0 < min <= max")
        if self.start_time_range[0] > self.start_time_range[1]:
            raise ValueError("start_time_range must satisfy min <= max")
        if len(set(self.sensor_positions)) != len(self.sensor_positions):
            raise ValueError("sensor_positions must be distinct")
        if min(self.sensor_positions) < 0:
            raise ValueError("sensor_positions must be >= 0 (targets enter the road at 0)")
        return self


DEFAULT_LANE_CHANGE_PROBABILITY = 0.1


class VehicleFeatures(BaseModel):
    """What detectors report beyond the paper's (position, velocity, timestamp): each vehicle's
    lane at every sensor, its length and its class. All off by default (the paper's detector).
    They are drawn from a random stream of their own, so the vehicles and their true passages are
    the same with them or without (the faults that read them, length noise and false alarms'
    features, draw from the faults' stream, so with faults on, which reports are faulty differs)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lanes: int | None = Field(
        default=None,
        ge=1,
        le=MAX_LANE + 1,
        description="Number of lanes, numbered from 0 (rightmost); each vehicle starts in a "
        "random one and every detection reports its lane. None: no lane reported.",
    )
    lane_change_probability: float = Field(
        default=DEFAULT_LANE_CHANGE_PROBABILITY,
        ge=0,
        le=1,
        description="Chance that a vehicle moves to a neighbouring lane between two consecutive "
        "sensors (needs lanes).",
    )
    vehicle_lengths: bool = Field(
        default=False,
        description="Every detection reports its vehicle's length: each vehicle is a car (80 %, "
        "3.6-5.4 m), van (10 %, 5-7 m), truck (8 %, 8-18 m) or bus (2 %, 12-15 m), its length "
        "uniform in its class's range; measured with length_noise.",
    )
    vehicle_classes: bool = Field(
        default=False,
        description="Every detection reports its vehicle's class ('car', 'van', 'truck', 'bus'; "
        "the same mix as vehicle_lengths).",
    )

    # A field validator (not a model one), so that the error names the field; `lanes` is
    # declared before it, so it has been validated by then.
    @field_validator("lane_change_probability")
    @classmethod
    def _lane_changes_need_lanes(cls, value: float, info: ValidationInfo) -> float:
        if info.data.get("lanes") is None and value != DEFAULT_LANE_CHANGE_PROBABILITY:
            raise ValueError("needs lanes (the number of lanes)")
        return value


# The traffic's fields come first, then the vehicle features', then the faults' (pydantic orders
# the fields of the bases from the last to the first): the order the API's SimulationOverrides
# lists them in, and the order that lets a fault's validator read the features.
class SimulationConfig(DetectorFaults, VehicleFeatures, Traffic):
    """Everything Algorithm 1 needs: the traffic, what its detectors report of each vehicle, and
    the faults of those detectors. Defaults are the paper's 'large' preset, with no features and
    no faults."""

    @field_validator("length_noise")
    @classmethod
    def _length_noise_needs_lengths(cls, value: float, info: ValidationInfo) -> float:
        if value and not info.data.get("vehicle_lengths"):
            raise ValueError("needs vehicle_lengths (otherwise no length is measured)")
        return value

    @property
    def faults(self) -> DetectorFaults:
        """The fault settings alone, as the fault model that every simulator shares takes them."""
        return DetectorFaults(**{name: getattr(self, name) for name in DetectorFaults.model_fields})


PRESETS: dict[str, SimulationConfig] = {
    # The paper's Tables I-III: 10 targets, a 1000 m road, a sensor every 100 m.
    "large": SimulationConfig(velocity_range=(30.0, 80.0), start_time_range=(1.0, 30.0)),
    "medium": SimulationConfig(velocity_range=(20.0, 50.0), start_time_range=(1.0, 30.0)),
    "small": SimulationConfig(velocity_range=(20.0, 40.0), start_time_range=(1.0, 20.0)),
    # Beyond the paper: dense multi-lane traffic (about 3,600 vehicles an hour) through a slow
    # zone that halves the speed over a fifth of the road.
    "congested": SimulationConfig(
        n_targets=120,
        velocity_range=(20.0, 40.0),
        start_time_range=(0.0, 120.0),
        slow_zone=SlowZone(start=400.0, end=600.0, speed_factor=0.5),
    ),
}


def preset(name: str, **overrides: object) -> SimulationConfig:
    """A preset with some settings changed (validated again)."""
    try:
        base = PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset '{name}'; known: {', '.join(PRESETS)}") from None
    return SimulationConfig.model_validate({**base.model_dump(), **overrides})
