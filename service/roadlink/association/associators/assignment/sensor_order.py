"""Two sensors whose positions are swapped: a deployment's registry that maps each detector to
the other's position, or two loops wired to each other's inputs.

Every vehicle then seems to pass the later of the two before the earlier, and the travel times
round the pair are off by a travel time or two: on SUMO's committed free flow, sensors 4 and 5
of 11 swapped, 61 % of the detections were grouped right (99 % as placed), without a word.
Each segment's lag (`clocks.Road.lags`: the travel times of its pairs of detections less the
kinematic prediction, where their histogram peaks clearly) tells it: round a swapped pair no
peak keeps time, and with the two sensors' detections taken the other way round, all three
segments' do. So a pair is taken the other way round where the segment between them does not
keep time as reported, and the segments round it (two at least) all do once exchanged. Queues,
whose lags sit a travel time off or spread, keep no time either way.
"""

from __future__ import annotations

import numpy as np

from roadlink.association.associators.assignment.clocks import CLOCK_LEAST_DETECTIONS, Lag, Road
from roadlink.association.detections import FloatArray, IntArray

# A segment keeps time where its lag's peak lies within this share of its typical travel time
# (and a bin) of the kinematic prediction.
KEPT_SHARE = 0.25


def swapped_pairs(
    positions: FloatArray, times: list[FloatArray], speeds: list[FloatArray]
) -> tuple[list[int], list[Lag | None] | None]:
    """Each k whose sensors k and k + 1 report each other's vehicles (the pairs apart, in road
    order), and every segment's lag as the sensors are reported (None where not measured: the
    clocks' search, which measures the same, takes them). `times[k]` are sensor k's detection
    times (ascending), `speeds[k]` their speeds."""
    n = positions.size
    # Fewer detections at a sensor and its segments' lags are not measured (`clocks`).
    if n < 3 or min(t.size for t in times) < CLOCK_LEAST_DETECTIONS:
        return [], None
    road = Road(positions, list(times), list(speeds))
    lags = road.lags(list(range(n - 1)))
    pairs: list[int] = []
    for k in range(n - 1):
        if keeps_time(lags[k]) or (pairs and pairs[-1] >= k - 1):
            continue
        exchanged = Road(positions, list(times), list(speeds))
        exchanged.times[k], exchanged.times[k + 1] = times[k + 1], times[k]
        exchanged.speeds[k], exchanged.speeds[k + 1] = speeds[k + 1], speeds[k]
        round_pair = [j for j in (k - 1, k, k + 1) if 0 <= j < n - 1]
        if all(keeps_time(lag) for lag in exchanged.lags(round_pair)):
            pairs.append(k)
    return pairs, lags


def keeps_time(lag: Lag | None) -> bool:
    """Whether a segment's lag peaks clearly within KEPT_SHARE of a travel time (and a bin)."""
    return lag is not None and abs(lag.seconds) <= KEPT_SHARE * lag.typical + lag.bin_width


def in_road_order(sensor: IntArray, pairs: list[int]) -> IntArray:
    """Each detection's sensor, the two of every swapped pair exchanged."""
    if not pairs:
        return sensor
    mapping = np.arange(int(sensor.max()) + 1)
    for k in pairs:
        mapping[k], mapping[k + 1] = k + 1, k
    result: IntArray = mapping[sensor]
    return result


def order_warnings(positions: FloatArray, pairs: tuple[int, ...]) -> list[str]:
    """A sentence for each pair taken the other way round, for whoever keeps the deployment's
    register of sensors (the association is not affected)."""
    return [
        f"the sensors at positions {positions[k]:g} and {positions[k + 1]:g} report each "
        "other's vehicles (every vehicle passes the later one first): their positions look "
        "swapped; they were taken the other way round for the association"
        for k in pairs
    ]
