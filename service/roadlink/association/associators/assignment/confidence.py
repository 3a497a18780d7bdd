"""How sure each link is: the approximate posterior probability that a link joins one vehicle.

At every sensor boundary the tracks are cut into prefixes and suffixes, as the re-pairing sweep
cuts them (`refine`), and every plausible way of joining them again competes with the links
chosen: a link whose rivals cost almost as little is a guess, one without rivals is sure. The
probability of each candidate join is the marginal of a one-to-one matching in which every piece
may also stay alone (at half the gate, as in the forward pass). Marginals of a matching are
exponentially hard to compute exactly (the permanent); Sinkhorn balancing of the joins'
likelihoods gives the Bethe approximation used in multi-target tracking (JPDA), in time linear
in the candidate joins. A link that spans several boundaries takes its least sure one.
"""

from __future__ import annotations

import numpy as np

from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import (
    SINKHORN_ITERATIONS,
    SINKHORN_TOLERANCE,
    AssignmentParams,
)
from roadlink.association.associators.assignment.refine import (
    boundary_cost,
    ends_at_boundary,
    prefix_sums,
    suffix_sums,
)
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.associators.assignment.tracks import successors, tracks_from_links
from roadlink.association.detections import FloatArray, IntArray


def link_confidence(
    s: Sensors, model: SegmentModel, params: AssignmentParams, track: IntArray
) -> FloatArray:
    """Per detection, the probability that the link into it from the previous detection of its
    track is right (NaN where it has no previous detection)."""
    nxt, prv = successors(s, track)
    in_track = track >= 0
    heads = prefix_sums(s, prv, in_track)
    tails = suffix_sums(s, nxt, in_track)
    confidence = np.full(track.size, np.nan)
    confidence[prv >= 0] = 1.0
    for k in range(1, s.positions.size):
        ends = ends_at_boundary(s, model, params, nxt, prv, in_track, k)
        if ends is None:
            continue
        _, pairs = ends
        cost = boundary_cost(params, model, pairs, heads, tails)
        chosen = nxt[pairs.a] == pairs.b
        marginal = matching_marginals(pairs, cost, params.gate_cost)
        b = pairs.b[chosen]
        confidence[b] = np.minimum(confidence[b], marginal[chosen])
    return confidence


def matching_marginals(pairs: Pairs, cost: FloatArray, gate: float) -> FloatArray:
    """Approximate probability of each candidate join in a one-to-one matching where every node
    may stay alone at cost gate / 2: a join's likelihood against leaving both its ends alone is
    w = exp(-(cost - gate) / 2).

    The matching is the square one the solver sees (`matching`): rows are the left nodes and a
    dummy per right node, columns the right nodes and a dummy per left node; a node pairs with
    its own dummy to stay alone, and dummies pair with each other along every join. Sinkhorn
    balancing scales rows and columns until each sums to one. It keeps the matrix's
    cross-ratios, so for a two-way choice it returns odds equal to the square root of their
    likelihood ratio: balancing the squared likelihoods makes those odds exact, for the two
    ambiguities that dominate, a join against leaving both ends alone, and two joins against
    their swap. Longer chains of rivals are approximated.
    """
    if cost.size == 0:
        return np.zeros(0)
    _, li = np.unique(pairs.a, return_inverse=True)
    _, ri = np.unique(pairs.b, return_inverse=True)
    n_l, n_r = int(li.max()) + 1, int(ri.max()) + 1
    # Squared likelihoods, relative to staying alone (whose weight is then 1).
    weight = np.exp(-(np.minimum(cost, 4.0 * gate) - gate))
    u = np.ones(n_l)  # rows: left nodes
    u_dummy = np.ones(n_r)  # rows: the right nodes' dummies
    v = np.ones(n_r)  # columns: right nodes
    v_dummy = np.ones(n_l)  # columns: the left nodes' dummies
    for _ in range(SINKHORN_ITERATIONS):
        u_next = 1.0 / (np.bincount(li, weight * v[ri], minlength=n_l) + v_dummy)
        u_dummy = 1.0 / (v + np.bincount(ri, v_dummy[li], minlength=n_r))
        v = 1.0 / (np.bincount(ri, weight * u_next[li], minlength=n_r) + u_dummy)
        v_dummy = 1.0 / (u_next + np.bincount(li, u_dummy[ri], minlength=n_l))
        done = np.max(np.abs(u_next - u)) < SINKHORN_TOLERANCE * np.max(u_next)
        u = u_next
        if done:
            break
    return np.asarray(u[li] * weight * v[ri], dtype=np.float64)


def cut_weak_links(
    s: Sensors, target: IntArray, confidence: FloatArray, min_confidence: float
) -> tuple[IntArray, FloatArray]:
    """The targets with every link less sure than `min_confidence` cut (each piece a target of
    its own, numbered anew), and the confidences of the links that remain (NaN elsewhere)."""
    kept = np.where(target >= 0, confidence, np.nan)
    if min_confidence <= 0.0:
        return target, kept
    _, prv = successors(s, target)
    weak = (prv >= 0) & (kept < min_confidence)
    prv[weak] = -1
    kept[weak] = np.nan
    return tracks_from_links(s, prv, target >= 0), kept
