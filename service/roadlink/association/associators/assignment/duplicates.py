"""A passage reported twice: which report may copy which, and the copy's place in the result.

Detectors re-trigger on one vehicle: the same sensor reports it again moments later at nearly
the same speed. Both reports are the vehicle's, but a track holds one detection a sensor, so
while tracks are built a copy never starts a track of its own (`tracks._births`), and once they
are built, a copy left out of every target joins its twin's (`join_duplicates`): it is one of
that vehicle's detections, and a user (and the scoring) finds it there rather than unassigned.
A report that repeats another exactly (`repeat_of`: a batch sent again) is set aside before
anything is linked, and takes its report's group at the end.
"""

from __future__ import annotations

import numpy as np

from roadlink.association.associators.assignment.features import NO_CLASS, SensorFeatures
from roadlink.association.associators.assignment.gating import GATE_AT_ONCE, BoolArray
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.detections import NO_LANE, Detections, FloatArray, IntArray

# Reports at one sensor and time that share their readings this many binomial standard
# deviations more often than consecutive reports do are repeats (`repeat_of`).
REPEAT_DEVIATIONS = 3.0


def duplicate_followers(s: Sensors, params: AssignmentParams) -> IntArray:
    """For every detection, the earlier report of the same sensor it may duplicate (-1 if none):
    within `duplicate_window` in time and `duplicate_velocity_tolerance` in speed, and, where
    both report them, in the same lane and of the same class (a copy reads them again; a vehicle
    in the next lane at the same speed is another vehicle).

    A copy copies a passage: its leader is never a copy itself, so a detector stuck repeating
    one reading makes pairs, not one passage of a hundred reports. Speeds floored (read below
    `velocity_floor` of the median: a crawl, a stop) are not alike: what they were is unknown."""
    n = s.time.size
    leader = np.full(n, -1, dtype=np.int64)
    if params.duplicate_window <= 0:
        return leader
    tolerance = np.log1p(params.duplicate_velocity_tolerance)
    readable = s.speed > s.speed_floor
    # With few reports a sensor (a paper-size batch), every sensor's at once, lag after lag (a
    # sensor's times ascend, and are finite, so once no two reports `lag` apart are close, none
    # further apart are); else sensor by sensor, so that one sensor's crowd of close reports
    # costs no pass over the others'. The nearest earlier report first.
    at_once = n <= GATE_AT_ONCE * s.positions.size
    runs = [s.order] if at_once else [s.members(k) for k in range(s.positions.size)]
    for m in runs:
        for lag in range(1, m.size):
            later, earlier = m[lag:], m[:-lag]
            close = s.time[later] - s.time[earlier] <= params.duplicate_window
            if at_once:
                close &= s.sensor[later] == s.sensor[earlier]
            if not close.any():
                break
            alike = close & (np.abs(s.log_speed[later] - s.log_speed[earlier]) <= tolerance)
            alike &= readable[later] & readable[earlier]
            if s.features is not None:
                alike &= _features_agree(s.features, later, earlier)
            fresh = alike & (leader[later] < 0)
            leader[later[fresh]] = earlier[fresh]
    _lead_from_roots(s, leader, params.duplicate_window, tolerance)
    return leader


def repeat_of(s: Sensors, d: Detections) -> IntArray | None:
    """For every report of `d` (arranged as `s`), the first in input order of the reports it
    repeats exactly: the same sensor, time and speed, and the same lane, length and class where
    reported (a gateway that sent a batch, or some rows, again; two feeds of one detector).
    Itself where it repeats none; None where no report repeats another. Such a report is never
    a vehicle of its own, nor any other vehicle's: the associator groups each report once and
    gives its repeats its group (`AssignmentAssociator.group`). Left among the others, a
    repeat was linked into a neighbour's track in dense traffic and took its place (SUMO's
    dense traffic sent twice: 69.3 %, against 95.4 % once).

    Reports of one sensor, time and speed sort next to each other in `s.order` (ties in input
    order), so one comparison of neighbours finds them; where features are reported, those
    runs are sorted again by lane, length and class."""
    o = s.order
    a, b = o[:-1], o[1:]
    same = (s.sensor[a] == s.sensor[b]) & (s.time[a] == s.time[b])
    same &= d.velocity[a] == d.velocity[b]
    if not same.any():
        return None
    run_start = np.r_[True, ~same]
    run = np.empty_like(o)
    run[o] = np.cumsum(run_start) - 1  # each report's run, by report
    if d.features:
        run = _split_by_features(d, run, o[np.r_[same, False] | np.r_[False, same]])
    if _alike_by_chance(s, d):
        return None
    first = np.full(run.max() + 1, o.size, dtype=np.int64)
    np.minimum.at(first, run, np.arange(o.size))
    result: IntArray = first[run]
    return None if (result == np.arange(o.size)).all() else result


def _alike_by_chance(s: Sensors, d: Detections) -> bool:
    """Whether the reports that share a sensor and a time also share their speed (and lane,
    length and class, where reported) no more often than a sensor's consecutive reports at
    different times do: detectors
    that stamp whole seconds and read whole km/h report two vehicles side by side alike by
    chance (SUMO's dense traffic so rounded: 164 of 1,719 reports), where a batch sent again
    repeats its reports exactly. Such reports are vehicles of their own, not repeats.

    Consecutive reports at different times share their reading as often as reports at one
    time would by chance (neighbours in time drive alike in both); the reports at one time may
    share it REPEAT_DEVIATIONS binomial standard deviations more often than that before any is a
    repeat."""
    o = s.order
    a, b = o[:-1], o[1:]
    one_sensor = s.sensor[a] == s.sensor[b]
    at_once = one_sensor & (s.time[a] == s.time[b])
    alike = (d.velocity[a] == d.velocity[b]) & _features_alike(d, a, b)
    apart = one_sensor & ~at_once
    if not apart.any():
        return False
    chance = np.count_nonzero(alike & apart) / np.count_nonzero(apart)
    tied = np.count_nonzero(at_once)
    expected = chance * tied
    spread = np.sqrt(expected * (1.0 - chance))
    return np.count_nonzero(alike & at_once) <= expected + REPEAT_DEVIATIONS * spread


def _features_alike(d: Detections, a: IntArray, b: IntArray) -> BoolArray:
    """Reports a and b read the same lane, length and class (True where not reported)."""
    alike = np.ones(a.size, dtype=bool)
    if d.lane is not None:
        alike &= d.lane[a] == d.lane[b]
    if d.length is not None:
        same_length = (d.length[a] == d.length[b]) | (np.isnan(d.length[a]) & np.isnan(d.length[b]))
        alike &= same_length
    if d.vehicle_class is not None:
        alike &= d.vehicle_class[a] == d.vehicle_class[b]
    return alike


def _split_by_features(d: Detections, run: IntArray, shared: IntArray) -> IntArray:
    """`run` (each report's run of one sensor, time and speed) split where the reports of a run
    (`shared`: those in a run of two or more) differ in lane, length or class."""
    length = np.where(np.isnan(d.length[shared]), -1.0, d.length[shared])
    _, kind = np.unique(d.vehicle_class[shared].astype(str), return_inverse=True)
    key = np.stack([run[shared], d.lane[shared], length, kind]).T
    _, split = np.unique(key, axis=0, return_inverse=True)
    result = run.copy()
    result[shared] = run.max() + 1 + split.ravel()
    return result


def once_each(repeats: IntArray) -> tuple[IntArray, IntArray]:
    """The reports kept once (those that repeat none, ascending) and, for every report, the
    place among them of the report it is (`repeat_of`)."""
    kept = np.flatnonzero(repeats == np.arange(repeats.size))
    return kept, np.searchsorted(kept, repeats)


def for_every_report(
    repeats: IntArray, kept: IntArray, at: IntArray, groups: IntArray, confidence: FloatArray
) -> tuple[IntArray, FloatArray]:
    """The `groups` and link `confidence` of the reports kept once (`once_each`) given to every
    report: a repeat takes its report's group, and no confidence (nothing links to it)."""
    every = np.full(repeats.size, np.nan)
    every[kept] = confidence
    result: IntArray = groups[at]
    return result, every


def _lead_from_roots(s: Sensors, leader: IntArray, window: float, tolerance: float) -> None:
    """Where a report's leader is a copy itself, it copies that copy's root passage if that lies
    within the window and speed tolerance too (a passage reported three times), and is a passage
    of its own if not. In time order, so every leader's own leader is final when it is read."""
    copies = np.flatnonzero(leader >= 0)
    chained = copies[leader[leader[copies]] >= 0]
    for c in chained[np.argsort(s.time[chained], kind="stable")].tolist():
        root = int(leader[leader[c]])
        if root < 0:
            continue  # its leader became a passage of its own, earlier in this loop
        close = s.time[c] - s.time[root] <= window
        alike = abs(s.log_speed[c] - s.log_speed[root]) <= tolerance
        leader[c] = root if close and alike else -1


def _features_agree(f: SensorFeatures, a: IntArray, b: IntArray) -> np.ndarray:
    """Whether each pair's lanes and classes agree where both report them."""
    lane_a, lane_b = f.lane[a], f.lane[b]
    class_a, class_b = f.vehicle_class[a], f.vehicle_class[b]
    same_lane = (lane_a == lane_b) | (lane_a == NO_LANE) | (lane_b == NO_LANE)
    same_class = (class_a == class_b) | (class_a == NO_CLASS) | (class_b == NO_CLASS)
    return same_lane & same_class


def join_duplicates(target: IntArray, leader: IntArray) -> IntArray:
    """`target` with each pair of reports that may be one passage (`leader`) where one is in a
    target and the other in none made one: the other joins that target. Either of the two may be
    the one left out (the tracks may have taken the copy). A copy of a copy joins too (a report
    reaches its target over as many copies as there are)."""
    joined = target.copy()
    follower = np.flatnonzero(leader >= 0)
    first = leader[follower]
    while True:
        forward = (joined[follower] < 0) & (joined[first] >= 0)
        backward = (joined[first] < 0) & (joined[follower] >= 0)
        if not (forward.any() or backward.any()):
            return joined
        joined[follower[forward]] = joined[first[forward]]
        # A report copied twice, its leader left out: the first copy in a target decides.
        back_from, back_to = follower[backward], first[backward]
        _, once = np.unique(back_to, return_index=True)
        joined[back_to[once]] = joined[back_from[once]]
