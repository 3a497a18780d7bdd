"""Stone Soup's global-nearest-neighbour tracker, set up for roadside detections.

This is what a tracking engineer would reach for instead of roadlink: a textbook multi-target
tracker. The mapping that makes it fit the problem is to swap the roles of time and space. Road
POSITION is the tracker's time axis, each sensor is one scan (in road order), and the state of a
target is [passing time t (s), pace dt/dx = 1/v (s/m)]. Each detection measures both (the pace
from its velocity), so the measurement is 2-D and the state fully observed. A constant-velocity
linear-Gaussian model in that space says "the pace stays the same from sensor to sensor", which
is exactly constant speed; its process noise absorbs the speed changes.

Settings, in the units of that space (seconds and seconds per metre), and why:

- `pace_diffusion` (q of `ConstantVelocity`, s^2/m^3): the pace random walk, whose variance
  grows by q per metre. The paper's speeds wander by about 5 % around v0 (10 s correlation
  time), which moves the pace by about 1e-3 s/m per 100 m: q near 1e-8 would do. But a slow
  zone halves the speed at once: at 30 m/s the pace jumps from 0.033 to 0.067 s/m, and for
  the model to find that plausible over one 100 m stretch, sqrt(q * 100) must be of that
  order, so q = 1e-5. The price is a loose time prediction (sd about 1.8 s per stretch) which
  the measured pace makes up for.
- `time_noise` (s): sensors here report exact passing times, but a Kalman filter needs R > 0;
  0.05 s is a loop detector's typical time resolution.
- `pace_noise` (s/m): the velocity is the speed at the sensor, while the pace that predicts the
  next passing time is the average over the next stretch; their difference is this noise.
- `gate` (Mahalanobis distance, `missed_distance`): the cost of leaving a track without a
  detection in a scan. A Gaussian gate (3.7 for 99.9 % in 2-D) is far too tight where speed
  changes are jumps, not a random walk: on the congested preset a gate of 30 gives 55 %
  accuracy, 100 gives 88 % (seeds 100-105, not those scored), so 100.
- `max_missed_scans`: a track not updated for this many sensors in a row is deleted; with no
  missed detections, a track that skips a sensor has lost its target.

Every detection that no track takes starts a track (`SimpleMeasurementInitiator`: the state is
fully measured, so one detection is enough), so each detection ends in exactly one track, and
each track is one group.
"""

from __future__ import annotations

import datetime
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from stonesoup.base import Property
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.deleter.time import UpdateTimeStepsDeleter
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.initiator.simple import SimpleMeasurementInitiator
from stonesoup.measures import Mahalanobis
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import ConstantVelocity
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.reader.base import DetectionReader
from stonesoup.tracker.simple import MultiTargetTracker
from stonesoup.types.detection import Detection
from stonesoup.types.state import GaussianState
from stonesoup.types.track import Track
from stonesoup.types.update import Update
from stonesoup.updater.kalman import KalmanUpdater

from roadlink.association.detections import Detections, IntArray

# Stone Soup's clock is a datetime; one metre of road is one second of tracker time.
ROAD_ORIGIN = datetime.datetime(2000, 1, 1)


@dataclass(frozen=True)
class TrackerSettings:
    """Noise, gate and deletion settings of the tracker (see the module docstring)."""

    pace_diffusion: float = 1e-5
    time_noise: float = 0.05
    pace_noise: float = 1e-3
    gate: float = 100.0
    max_missed_scans: int = 1


class SensorScans(DetectionReader):
    """The detections of each sensor, in road order, as Stone Soup scans."""

    scans: list[tuple[datetime.datetime, set[Detection]]] = Property(doc="(time, detections)")

    @DetectionReader.generator_method
    def detections_gen(self) -> Iterator[tuple[datetime.datetime, set[Detection]]]:
        yield from self.scans


def sensor_scans(detections: Detections, measurement_model: LinearGaussian) -> SensorScans:
    """One scan per sensor position; each detection carries its row index in `metadata`."""
    pace = 1.0 / detections.velocity
    scans = []
    for position in detections.sensor_positions:
        when = ROAD_ORIGIN + datetime.timedelta(seconds=float(position))
        rows = np.flatnonzero(detections.position == position)
        scan = {
            Detection(
                np.array([[detections.timestamp[row]], [pace[row]]]),
                timestamp=when,
                measurement_model=measurement_model,
                metadata={"row": int(row)},
            )
            for row in rows
        }
        scans.append((when, scan))
    return SensorScans(scans)


def gnn_tracker(
    detections: Detections, settings: TrackerSettings | None = None
) -> MultiTargetTracker:
    """A GNN tracker (2-D assignment per scan) over these detections, ready to iterate."""
    s = settings or TrackerSettings()
    transition = ConstantVelocity(s.pace_diffusion)
    measurement = LinearGaussian(
        ndim_state=2, mapping=(0, 1), noise_covar=np.diag([s.time_noise**2, s.pace_noise**2])
    )
    predictor = KalmanPredictor(transition)
    updater = KalmanUpdater(measurement)
    hypothesiser = DistanceHypothesiser(
        predictor, updater, measure=Mahalanobis(), missed_distance=s.gate
    )
    # Both dimensions are measured, so the prior only has to be a valid 2-D Gaussian.
    prior = GaussianState(np.zeros((2, 1)), np.zeros((2, 2)))
    return MultiTargetTracker(
        initiator=SimpleMeasurementInitiator(prior, measurement),
        deleter=UpdateTimeStepsDeleter(s.max_missed_scans + 1),
        detector=sensor_scans(detections, measurement),
        data_associator=GNNWith2DAssignment(hypothesiser),
        updater=updater,
    )


def track_groups(detections: Detections, settings: TrackerSettings | None = None) -> IntArray:
    """Run the tracker over the detections; group index of each detection = its track."""
    tracker = gnn_tracker(detections, settings)
    every_track: set[Track] = set()
    for _, tracks in tracker:
        # A deleted track leaves the tracker's set, so collect each one while it is alive.
        every_track |= tracks
    groups = np.full(len(detections), -1, dtype=np.int64)
    for index, track in enumerate(every_track):
        for state in track.states:
            if isinstance(state, Update) and state.hypothesis.measurement is not None:
                groups[state.hypothesis.measurement.metadata["row"]] = index
    return groups
