"""Simulation settings: the paper's Tables I-III as presets, plus the faults it leaves for later."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

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


# The traffic's fields come first, then the faults' (pydantic orders the fields of the bases
# from the last to the first): the order the API's SimulationOverrides lists them in.
class SimulationConfig(DetectorFaults, Traffic):
    """Everything Algorithm 1 needs: the traffic, and the faults of the detectors that see it.
    Defaults are the paper's 'large' preset, with no faults."""

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
