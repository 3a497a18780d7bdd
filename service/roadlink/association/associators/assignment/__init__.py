"""`assignment`: track building by sparse minimum-cost assignment, sensor after sensor.

The paper clusters detections as independent points. They are not: a target passes each sensor
once, in position order, and its speed changes little between neighbouring sensors. This
associator uses that structure. Its stages, each in a module of this package, in the order the
loop (`associator`) runs them:

- `sensors`: the detections arranged by sensor in road order, speeds floored; and the kinematic
  travel time, `dx * ((1 - skew) / v_a + skew / v_b)`, that every stage predicts from.
- `params`: the parameters, every fixed hyper-parameter, and the parameters in time units held
  to the detections' own time scale (`within_time_scale`).
- `prior`: before anything is linked, each segment's travel-time bias is the mode of
  log(observed / kinematic travel time) over the pairs of its end sensors' detections.
- `model`: the segment model a link is costed with (`SegmentModel`) and the heavy tails of its
  residuals (`Tails`): in real traffic a few per cent of the links lie 5 to 20 core spreads
  off, and a Gaussian cost would break them.
- `gating`: candidate links from one sensor's detections to a later sensor's, gated in time
  (sorted times and `searchsorted`), so the work grows with the number of detections, not its
  square.
- `costs`: a link's cost, a kinematic negative log-likelihood: the travel-time error, the speed
  change, a speed far from the track's own pace (each residual costs -2 log of its learned,
  heavy-tailed density), and a penalty for each sensor skipped.
- `matching`: minimum-cost one-to-one matching (sparse LAPJVsp, every node free to stay alone).
- `tracks`: sensors are visited in road order; at each, the open tracks (whose last detection
  lies at one of the previous `max_skip + 1` sensors, so a missed detection is bridged) are
  matched to its detections. A detection left unmatched starts a track (a birth), a track left
  unmatched waits (a miss); links costlier than `gate_cost` are never made. Duplicated reports
  (one passage reported twice) never start a track of their own.
- `learning`: each segment's behaviour (travel-time bias, skew and spread, speed ratio and its
  spread) and the tails, learned robustly (median, MAD) from the confident tracks' links; the
  tracks are then built again with it: a few EM-style rounds.
- `ends`: where vehicles leave or join the road between sensors (junctions' ramps), read off the
  first tracks: links out of and into such a sensor pay what staying unmatched saves there.
- `refine`: the sequential pass chooses each link knowing only the past, so the tracks are then
  re-paired with hindsight: at every sensor boundary, track prefixes are matched to track
  suffixes again, each seen whole.
- `confirmation`: tracks shorter than `min_track_length`, or whose links save too little over
  leaving their detections apart, are false alarms (-1), unless the batch's time window cut
  them (a vehicle that passed the first sensor in the batch's last seconds is seen once, and is
  a target).
- `confidence`: every link's approximate probability of being right, judged against its rivals
  at its sensor boundary (in the last re-pairing sweep, `matching.chosen_marginals`), and
  `min_confidence`'s cut of the weaker links into targets of their own.
"""

from roadlink.association.associators.assignment.associator import AssignmentAssociator
from roadlink.association.associators.assignment.model import SegmentModel, Tails
from roadlink.association.associators.assignment.params import (
    AssignmentParams,
    within_time_scale,
)

__all__ = ["AssignmentAssociator", "AssignmentParams", "SegmentModel", "Tails", "within_time_scale"]
