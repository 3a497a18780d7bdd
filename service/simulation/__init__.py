"""The paper's data generation (Algorithm 1), with presets and faults."""

from service.simulation.config import PRESETS, SimulationConfig, SlowZone, preset
from service.simulation.generate import Simulation, Trajectory, simulate

__all__ = [
    "PRESETS",
    "Simulation",
    "SimulationConfig",
    "SlowZone",
    "Trajectory",
    "preset",
    "simulate",
]
