"""A queue's silences: where a link over a sensor cannot have passed it unseen.

A link over a missed sensor says that a vehicle passed it between the link's ends and the
detector missed it. Where a queue stands still on a sensor, it reports nothing for minutes,
and vehicles waiting behind it were linked over it to vehicles that had passed it before the
queue stopped (SUMO's committed queue: all 122 such links wrong). A vehicle missed at random
passes among others that the sensor reports, a headway or two either side; so a link is not
made where it would have passed a sensor inside a silence: a gap between two of the sensor's
reports many times longer than its headways around it, both reports slow (the queue's, read
against the road's fastest traffic; a detector that fails for a while in flowing traffic has
fast reports round its gap, and links over it are the only way through).
"""

from __future__ import annotations

import numpy as np

from roadlink.association.associators.assignment.params import FLOWING_SHARE
from roadlink.association.associators.assignment.sensors import (
    BoolArray,
    Sensors,
    arrival_keys_of,
)
from roadlink.association.detections import IntArray

# A silence is a gap longer than this many of its sensor's median headways around it ...
SILENCE_HEADWAYS = 10.0
# ... those of this many consecutive gaps, centred on it ...
LOCAL_GAPS = 21
# ... between two reports both slower than traffic flows (`params.FLOWING_SHARE` of the road's
# fastest sensor's median).
# Gaps whose local medians are worked out at once (about 8 MB of gaps).
LOCAL_CHUNK = 50_000


def silent_gaps(s: Sensors) -> BoolArray:
    """For every place in `s.order`, whether the gap from its sensor's report before it to it
    is a silence (False for each sensor's first report)."""
    time = s.sorted_time
    silent = np.zeros(time.size, dtype=bool)
    slow = s.speed[s.order] < FLOWING_SHARE * float(s.median_speed.max())
    # Only a gap between two slow reports of one sensor can be a silence: its local median is
    # worked out there alone (in a busy batch few gaps are).
    candidate = slow[1:] & slow[:-1]
    candidate[s.start[1:-1] - 1] = False  # a sensor's first report follows another's last
    places = np.flatnonzero(candidate) + 1
    if places.size == 0:
        return silent
    sensor = s.sensor[s.order[places]]
    first_gap, last_gap = s.start[sensor] + 1, s.start[sensor + 1] - 1
    gaps = np.diff(time, prepend=np.nan)
    half = LOCAL_GAPS // 2
    for lo in range(0, places.size, LOCAL_CHUNK):
        chunk = slice(lo, lo + LOCAL_CHUNK)
        # The gaps around each, those past its sensor's first or last gap repeating it.
        around = places[chunk, None] + np.arange(-half, half + 1)
        np.clip(around, first_gap[chunk, None], last_gap[chunk, None], out=around)
        local = np.median(gaps[around], axis=1)
        silent[places[chunk]] = gaps[places[chunk]] > SILENCE_HEADWAYS * local
    return silent


def over_silence(s: Sensors, a: IntArray, b: IntArray, span: IntArray) -> BoolArray:
    """Whether each link a -> b over `span` - 1 missed sensors would have passed one of them
    inside a silence: at any time it could have, all inside one silent gap. It could have
    passed it from the time the road's fastest speed takes from a to it until the time that
    speed takes from it to b (where it stopped on the way is unknown)."""
    result = np.zeros(a.size, dtype=bool)
    skips = np.flatnonzero(span > 1)
    keys = s.arrival_keys
    if skips.size == 0 or keys is None or not s.silent_gaps.any():
        return result
    a, b, span = a[skips], b[skips], span[skips]
    near = s.sensor[a]
    x_a, x_b = s.positions[near], s.positions[s.sensor[b]]
    t_a, t_b = s.time[a], s.time[b]
    fastest = float(s.top_speed.max())
    for offset in range(1, int(span.max())):
        which = np.flatnonzero(span > offset)
        q = near[which] + offset
        ends = (t_a[which], t_b[which])
        reached = np.clip(ends[0] + (s.positions[q] - x_a[which]) / fastest, *ends)
        left = np.clip(ends[1] - (x_b[which] - s.positions[q]) / fastest, *ends)
        place = keys.searchsorted(arrival_keys_of(q, reached))
        inside = (place > s.start[q]) & (place < s.start[q + 1])
        inside &= place == keys.searchsorted(arrival_keys_of(q, left))
        hit = which[inside]
        result[skips[hit]] |= s.silent_gaps[place[inside]]
    return result
