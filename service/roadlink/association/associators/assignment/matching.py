"""Minimum-cost one-to-one matching of a sparse bipartite graph, every node free to stay alone.

A generic solver: it knows edges and their costs, nothing of detections or tracks.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from scipy.sparse import csr_matrix

Nodes = npt.NDArray[np.int64]
Costs = npt.NDArray[np.float64]
Mask = npt.NDArray[np.bool_]

# Odds beyond e^40 either way are certainty (`chosen_marginals`): clipped, so that sums of
# ratios stay finite.
LOG_ODDS_LIMIT = 40.0

BATCH_EDGES = 2000  # edges per sparse assignment: small enough to stay linear, few enough calls
COST_QUANTUM_INVERSE = 1024.0  # sparse matching's costs are whole multiples of its inverse
DENSE_NODES = 120  # below this many nodes one dense assignment beats sparse bookkeeping
SHORT_NODES = 64  # up to this many node ids, Python's set and dict beat numpy's unique


def unique_inverse(nodes: Nodes) -> tuple[Nodes, Nodes]:
    """np.unique(nodes, return_inverse=True) of node ids, the same arrays; quick for a few."""
    if nodes.size > SHORT_NODES:
        unique, inverse = np.unique(nodes, return_inverse=True)
        return unique, inverse
    ids = nodes.tolist()
    distinct = sorted(set(ids))
    where = {node: k for k, node in enumerate(distinct)}
    return (
        np.array(distinct, dtype=nodes.dtype),
        np.array([where[node] for node in ids], dtype=np.int64),
    )


def match(left: Nodes, right: Nodes, cost: Costs, gate: float) -> tuple[Nodes, Nodes]:
    """Minimum-cost one-to-one matching of the (left, right, cost) edges, every node free to stay
    unmatched at cost gate / 2 (so an edge is taken only if it beats leaving both ends alone).

    The gated graph falls apart into many small connected components (nodes far apart never
    compete), which are solved independently: an isolated edge is simply taken, the others are
    solved a batch of components at a time, which keeps every sparse assignment small
    (LAPJVsp's shortest-path phase costs in proportion to the graph for every free row, so one
    huge call would be quadratic).
    """
    keep = cost < gate
    left, right, cost = left[keep], right[keep], cost[keep]
    if left.size == 0:
        return left, right
    lu, li = unique_inverse(left)
    ru, ri = unique_inverse(right)
    n_l, n_r = lu.size, ru.size
    if n_l + n_r <= DENSE_NODES:
        if n_l == left.size and n_r == right.size:
            # No two edges share a node, and each beats leaving its ends alone: all are taken
            # (by left, as the dense assignment returns them).
            by_left = np.argsort(li)
            return left[by_left], right[by_left]
        ml, mr = _match_dense(li, ri, cost, gate / 2.0, n_l, n_r)
        return lu[ml], ru[mr]
    # Imported on first use (pipeline.DEFERRED_IMPORTS): every CLI command would pay for it.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(li.size), (li, n_l + ri)), shape=(n_l + n_r, n_l + n_r))
    n_parts, part = connected_components(graph, directed=False)
    edge_part = part[li]
    edges_in_part = np.bincount(edge_part, minlength=n_parts)
    alone = edges_in_part[edge_part] == 1
    taken_l = [li[alone]]
    taken_r = [ri[alone]]
    for block in _component_batches(np.flatnonzero(~alone), edge_part, edges_in_part):
        bl, br = _match_block(li[block], ri[block], cost[block], gate / 2.0)
        taken_l.append(bl)
        taken_r.append(br)
    return lu[np.concatenate(taken_l)], ru[np.concatenate(taken_r)]


def _component_batches(shared: Nodes, edge_part: Nodes, edges_in_part: Nodes) -> list[Nodes]:
    """The edges `shared` in batches of whole components, about BATCH_EDGES edges each."""
    if shared.size == 0:
        return []
    order = shared[np.argsort(edge_part[shared], kind="stable")]
    parts = edge_part[order]
    boundary = np.flatnonzero(np.r_[True, parts[1:] != parts[:-1]])
    batch_of_part = np.cumsum(edges_in_part[parts[boundary]]) // BATCH_EDGES
    batch = np.repeat(batch_of_part, np.diff(np.r_[boundary, order.size]))
    cuts = np.flatnonzero(np.r_[True, batch[1:] != batch[:-1], True])
    return [order[lo:hi] for lo, hi in itertools.pairwise(cuts)]


def _match_dense(
    li: Nodes, ri: Nodes, cost: Costs, alone: float, n_l: int, n_r: int
) -> tuple[Nodes, Nodes]:
    """The same matching as `_match_block`, as one dense square assignment, for small problems
    (a paper-sized batch): building sparse graphs and their components costs far more there.

    Rows are the lefts, then one dummy per right; columns the rights, then one dummy per left. A
    left may take a real right along an edge or its own dummy (cost `alone`); dummies pair freely
    at no cost, which always leaves exactly as many free dummy rows as free dummy columns.
    """
    square = np.full((n_l + n_r, n_r + n_l), np.inf)
    square[li, ri] = cost
    square[np.arange(n_l), n_r + np.arange(n_l)] = alone
    square[n_l + np.arange(n_r), np.arange(n_r)] = alone
    square[n_l:, n_r:] = 0.0
    from scipy.optimize import linear_sum_assignment  # on first use, as in `match`

    row, col = linear_sum_assignment(square)
    real = (row < n_l) & (col < n_r)
    return row[real], col[real]


def _match_block(left: Nodes, right: Nodes, cost: Costs, alone: float) -> tuple[Nodes, Nodes]:
    """Exact min-cost matching of some edges, each node free to stay unmatched at cost `alone`.

    Sparse LAPJVsp on the graph augmented with one dummy node per real node: left l may match its
    own dummy (stay alone), right r may match its own dummy, and dummies match each other along
    every real edge so a full matching always exists.
    """
    lu, li = unique_inverse(left)
    ru, ri = unique_inverse(right)
    graph = _augmented(li, ri, cost, alone, lu.size, ru.size)
    from scipy.sparse.csgraph import min_weight_full_bipartite_matching  # as in `match`

    row, col = min_weight_full_bipartite_matching(graph)
    real = (row < lu.size) & (col < ru.size)
    return lu[row[real]], ru[col[real]]


def _augmented(li: Nodes, ri: Nodes, cost: Costs, alone: float, n_l: int, n_r: int) -> csr_matrix:
    """The graph `_match_block` solves, in canonical CSR form (each row's columns ascending),
    built directly: scipy's general COO -> CSR conversion and index sort cost more than the
    matching itself on the small blocks the associator has.

    Rows: real lefts [0, n_l), dummies of rights [n_l, n_l + n_r). Columns: real rights
    [0, n_r), dummies of lefts [n_r, n_r + n_l). Real left l: its edges (by right), then its
    own dummy n_r + l at cost `alone`; dummy of right r: r itself at `alone`, then the dummies
    of r's lefts (by left) at 0, so a full matching always exists.
    """
    from scipy.sparse import csr_matrix  # on first use, as in `match`

    # All weights rounded to whole multiples of 2^-10, so that every sum LAPJVsp forms is
    # exact: with arbitrary floats its rounding errors can make it cycle forever (seen on a
    # dense block of SUMO traffic; tests/data/lapjvsp_cycle.npz). The rounding changes costs by
    # < 0.001. Then shifted to at least +1: LAPJVsp needs non-zero weights, and a full matching
    # has a fixed number of edges, so the shift changes nothing. (Costs are negative only where
    # detector features make a link more likely than not.)
    edge = np.round(cost * COST_QUANTUM_INVERSE) / COST_QUANTUM_INVERSE
    single = float(np.round(alone * COST_QUANTUM_INVERSE) / COST_QUANTUM_INVERSE)
    lowest = min(0.0, single, float(edge.min(initial=0.0)))
    shift = 1.0 - lowest
    n_edges = li.size
    by_left = np.argsort(li * n_r + ri)  # by left, then right
    if np.any(np.diff((li * n_r + ri)[by_left]) == 0):
        # An edge given twice: as scipy's conversion would, sum the two.
        rows = np.concatenate([li, np.arange(n_l), n_l + np.arange(n_r), n_l + ri])
        cols = np.concatenate([ri, n_r + np.arange(n_l), np.arange(n_r), n_r + li])
        weights = np.concatenate([edge, np.full(n_l + n_r, single), np.zeros(n_edges)]) + shift
        graph = csr_matrix((weights, (rows, cols)), shape=(n_l + n_r, n_r + n_l))
        graph.sum_duplicates()
        return graph
    degree_l = np.bincount(li, minlength=n_l)
    degree_r = np.bincount(ri, minlength=n_r)
    indptr = np.zeros(n_l + n_r + 1, dtype=np.int64)
    np.cumsum(np.concatenate([degree_l, degree_r]) + 1, out=indptr[1:])
    indices = np.empty(indptr[-1], dtype=np.int64)
    data = np.empty(indptr[-1])
    # A row's k-th entry sits at indptr[row] + k; its edges come in sorted order.
    rank = np.arange(n_edges) - (np.cumsum(degree_l) - degree_l)[li[by_left]]
    at = indptr[li[by_left]] + rank
    indices[at] = ri[by_left]
    data[at] = edge[by_left] + shift
    own = indptr[1 : n_l + 1] - 1
    indices[own] = n_r + np.arange(n_l)
    data[own] = single + shift
    by_right = np.argsort(ri * n_l + li)  # by right, then left
    rank = np.arange(n_edges) - (np.cumsum(degree_r) - degree_r)[ri[by_right]]
    start = indptr[n_l + ri[by_right]]
    indices[start + 1 + rank] = n_r + li[by_right]
    data[start + 1 + rank] = 0.0 + shift
    first = indptr[n_l : n_l + n_r]
    indices[first] = np.arange(n_r)
    data[first] = single + shift
    return csr_matrix((data, indices, indptr), shape=(n_l + n_r, n_r + n_l))


def chosen_marginals(left: Nodes, right: Nodes, cost: Costs, chosen: Mask, gate: float) -> Costs:
    """For each chosen edge of a one-to-one matching (`chosen` marks them among the candidate
    edges left -> right), the approximate probability that it is in the matching, every node
    free to stay alone at cost gate / 2; NaN for the other edges.

    The odds against a chosen edge sum the likelihood ratios of the matchings one move away:
    the edge dropped (both ends alone), one of its ends taking a free node instead, and the edge
    swapping partners with another chosen edge, or dropping it for a candidate that joins the
    two's far ends."""
    n = cost.size
    marginal = np.full(n, np.nan)
    if not chosen.any():
        return marginal
    _, li = unique_inverse(left)
    _, ri = unique_inverse(right)
    # Log likelihood of each edge against leaving both its ends alone.
    log_w = np.clip(-0.5 * (cost - gate), -LOG_ODDS_LIMIT, LOG_ODDS_LIMIT)
    edge_of_left = np.full(li.max() + 1, -1, dtype=np.int64)
    edge_of_right = np.full(ri.max() + 1, -1, dtype=np.int64)
    picked = np.flatnonzero(chosen)
    edge_of_left[li[picked]] = picked
    edge_of_right[ri[picked]] = picked
    against = np.zeros(n)
    against[picked] = np.exp(-log_w[picked])  # the edge dropped
    rival = np.flatnonzero(~chosen)
    ea, eb = edge_of_left[li[rival]], edge_of_right[ri[rival]]
    # One end takes the free node at the rival's other end.
    only_a = (ea >= 0) & (eb < 0)
    np.add.at(against, ea[only_a], np.exp(log_w[rival[only_a]] - log_w[ea[only_a]]))
    only_b = (ea < 0) & (eb >= 0)
    np.add.at(against, eb[only_b], np.exp(log_w[rival[only_b]] - log_w[eb[only_b]]))
    # Both ends taken: the rival replaces both chosen edges, and with it their far ends join
    # when that edge is a candidate too (a swap, counted once, from the rival of lower index).
    both = (ea >= 0) & (eb >= 0)
    f, ea, eb = rival[both], ea[both], eb[both]
    keys = li * (ri.max() + 1) + ri
    order = np.argsort(keys)
    wanted = li[eb] * (ri.max() + 1) + ri[ea]
    at = np.minimum(np.searchsorted(keys[order], wanted), n - 1)
    g = np.where(keys[order][at] == wanted, order[at], -1)
    lonely = log_w[f] - log_w[ea] - log_w[eb]
    swapped = np.where(g >= 0, lonely + log_w[np.maximum(g, 0)], -np.inf)
    counted = (g < 0) | (f < g)
    ratio = np.exp(lonely) + np.where(counted, np.exp(swapped), 0.0)
    np.add.at(against, ea, ratio)
    np.add.at(against, eb, ratio)
    marginal[picked] = 1.0 / (1.0 + against[picked])
    return marginal
