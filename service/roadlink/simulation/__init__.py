"""The paper's data generation (Algorithm 1), with presets and faults."""

from roadlink.simulation.config import PRESETS, SimulationConfig, SlowZone, preset
from roadlink.simulation.generate import Simulation, Trajectory, simulate

__all__ = [
    "PRESETS",
    "Simulation",
    "SimulationConfig",
    "SlowZone",
    "Trajectory",
    "preset",
    "simulate",
]
