"""Minimum-cost one-to-one matching of a sparse bipartite graph, every node free to stay alone.

A generic solver: it knows edges and their costs, nothing of detections or tracks.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
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
NARROW_RANGE = 4  # ids spanning under this many times their number: a table beats a sort


def unique_inverse(nodes: Nodes) -> tuple[Nodes, Nodes]:
    """np.unique(nodes, return_inverse=True) of node ids, the same arrays; quick for a few, and
    for many within a narrow range (a sensor's neighbours' detections, when the ids follow
    the road): marked in a table of the range instead of sorted."""
    if nodes.size > SHORT_NODES:
        lo, hi = int(nodes.min()), int(nodes.max())
        if hi - lo >= NARROW_RANGE * nodes.size:
            unique, inverse = np.unique(nodes, return_inverse=True)
            return unique, inverse
        shifted = nodes - lo
        present = np.zeros(hi - lo + 1, dtype=bool)
        present[shifted] = True
        unique = np.flatnonzero(present).astype(nodes.dtype)
        unique += lo
        rank = np.cumsum(present) - 1
        return unique, rank[shifted]
    ids = nodes.tolist()
    distinct = sorted(set(ids))
    where = {node: k for k, node in enumerate(distinct)}
    return (
        np.array(distinct, dtype=nodes.dtype),
        np.array([where[node] for node in ids], dtype=np.int64),
    )


def _distinct(nodes: Nodes) -> bool:
    """Whether no node occurs twice (a handful of them)."""
    ids = nodes.tolist()
    return len(set(ids)) == len(ids)


def match(left: Nodes, right: Nodes, cost: Costs, gate: float) -> tuple[Nodes, Nodes]:
    """Minimum-cost one-to-one matching of the (left, right, cost) edges, every node free to stay
    unmatched at cost gate / 2 (so an edge is taken only if it beats leaving both ends alone).

    The gated graph falls apart into many small connected components (nodes far apart never
    compete), which are solved independently: an isolated edge is simply taken, the others are
    solved a batch of components at a time, which keeps every sparse assignment small
    (LAPJVsp's shortest-path phase costs in proportion to the graph for every free row, so one
    huge call would be quadratic).
    """
    keep = (cost < gate).nonzero()[0]  # places, once: quicker than the mask three times
    left, right, cost = left[keep], right[keep], cost[keep]
    if left.size == 0:
        return left, right
    if 2 * left.size <= DENSE_NODES and _distinct(left) and _distinct(right):
        # No two edges share a node, and each beats leaving its ends alone: all are taken (by
        # left, as the dense assignment returns them; the lefts' ranks sort as the lefts).
        by_left = left.argsort()
        return left[by_left], right[by_left]
    lu, li = unique_inverse(left)
    ru, ri = unique_inverse(right)
    n_l, n_r = lu.size, ru.size
    if n_l + n_r <= DENSE_NODES:
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
    order, cuts = _component_batches(np.flatnonzero(~alone), edge_part, edges_in_part)
    taken_l, taken_r = _match_batches(li, ri, cost, gate / 2.0, order, cuts)
    return lu[np.concatenate([li[alone], *taken_l])], ru[np.concatenate([ri[alone], *taken_r])]


# How much cheaper each chosen edge must be than every rival at its nodes, and than leaving its
# ends alone, for `sure_matchings` to call it certain: far beyond a dense assignment's rounding
# (~1e-13 on costs of a gate's size) and the sparse one's quantum (1 / COST_QUANTUM_INVERSE),
# so that no solver's ties or rounding could prefer another matching.
SURE_MARGIN = 8.0 / COST_QUANTUM_INVERSE
SURE_TABLE = 16  # `sure_matchings`' nodes by id up to this many times as many as its edges


def matched_cost(left: Nodes, right: Nodes, cost: Costs, gate: float) -> float:
    """The cost of the cheapest matching of the (left, right) edges (each pair of nodes once),
    each node left alone costing half the gate: two costings of the same edges compare by their
    matched edges' savings alone."""
    linked_left, linked_right = match(left, right, cost, gate)
    taken = np.zeros(left.size, dtype=bool)
    if linked_left.size:
        # Each node is matched at most once: an edge is taken where its left node's partner is
        # its right one.
        by_left = np.argsort(linked_left)
        at = np.minimum(np.searchsorted(linked_left[by_left], left), linked_left.size - 1)
        taken = (linked_left[by_left][at] == left) & (linked_right[by_left][at] == right)
    alone = np.unique(left).size + np.unique(right).size - 2 * linked_left.size
    return float(cost[taken].sum()) + gate / 2 * alone


def sure_matchings(
    left: Nodes, right: Nodes, cost: Costs, group: Nodes, chosen: Mask, gate: float, groups: int
) -> Mask:
    """For `groups` independent matchings (edge i belongs to matching `group[i]`; node ids are a
    matching's own), whether `match` of each surely takes exactly its `chosen`
    edges under the gate, so that it need not be solved.

    It does where the chosen edges share no node, every node with an edge under the gate has a
    chosen one, and each chosen edge beats by SURE_MARGIN every other edge at its nodes and
    leaving its ends alone (the gate): then every node fares strictly better in the chosen
    matching than in any other (an edge's cost split between its ends, gate / 2 for a node
    alone), which is the one optimum. A paper-size batch's forward pass that rebuilds the round
    before's tracks, and a sweep that keeps its links, are mostly such matchings."""
    under = cost < gate
    chosen = chosen & under
    # Each node numbered among all matchings' nodes: by matching and id where that table is
    # short, else by rank (a road of many sensors has many matchings of few nodes; the table
    # stays within a few times the edges).
    width = int(max(left.max(initial=-1), right.max(initial=-1))) + 1
    left_key, right_key = group * width + left, group * width + right
    size = groups * width
    if size > SURE_TABLE * (left.size + 1):
        left_key, right_key = unique_inverse(left_key)[1], unique_inverse(right_key)[1]
        size = left.size
    at_left = np.empty(size)  # the chosen edge's cost at each node, NaN: none
    at_left.fill(np.nan)
    at_right = at_left.copy()
    at_left[left_key[chosen]] = cost[chosen]
    at_right[right_key[chosen]] = cost[chosen]
    # Every other edge under the gate costs more than the chosen ones at both its ends (NaN,
    # a node without a chosen edge, compares false).
    rival = under & ~chosen
    ok = ~rival | (
        (cost > at_left[left_key] + SURE_MARGIN) & (cost > at_right[right_key] + SURE_MARGIN)
    )
    ok &= ~chosen | (cost < gate - SURE_MARGIN)
    # No node in two chosen edges.
    ok &= ~chosen | (np.bincount(left_key[chosen], minlength=at_left.size)[left_key] == 1)
    ok &= ~chosen | (np.bincount(right_key[chosen], minlength=at_left.size)[right_key] == 1)
    sure: Mask = np.bincount(group[~ok], minlength=groups) == 0
    return sure


def _component_batches(
    shared: Nodes, edge_part: Nodes, edges_in_part: Nodes
) -> tuple[Nodes, Nodes]:
    """The edges `shared` in batches of whole components, about BATCH_EDGES edges each: the
    edges by component, and where each batch starts (and the last ends) among them."""
    if shared.size == 0:
        return shared, np.zeros(1, dtype=np.int64)
    order = shared[np.argsort(edge_part[shared], kind="stable")]
    parts = edge_part[order]
    boundary = np.flatnonzero(np.r_[True, parts[1:] != parts[:-1]])
    batch_of_part = np.cumsum(edges_in_part[parts[boundary]]) // BATCH_EDGES
    batch = np.repeat(batch_of_part, np.diff(np.r_[boundary, order.size]))
    return order, np.flatnonzero(np.r_[True, batch[1:] != batch[:-1], True])


def _match_dense(
    li: Nodes, ri: Nodes, cost: Costs, alone: float, n_l: int, n_r: int
) -> tuple[Nodes, Nodes]:
    """The same matching as `_match_batches`, as one dense square assignment, for small problems
    (a paper-sized batch): building sparse graphs and their components costs far more there.

    Rows are the lefts, then one dummy per right; columns the rights, then one dummy per left. A
    left may take a real right along an edge or its own dummy (cost `alone`); dummies pair freely
    at no cost, which always leaves exactly as many free dummy rows as free dummy columns.
    """
    size = n_l + n_r
    square = np.empty((size, size))  # np.full's array, without its Python-level steps
    square.fill(np.inf)
    square[li, ri] = cost
    # The dummies' diagonals, (l, n_r + l) and (n_l + r, r), as strided runs of the flat square.
    flat = square.reshape(-1)
    flat[n_r : n_r + n_l * (size + 1) : size + 1] = alone
    flat[n_l * size : n_l * size + n_r * (size + 1) : size + 1] = alone
    square[n_l:, n_r:] = 0.0
    row, col = _dense_solver()(square)
    real = (row < n_l) & (col < n_r)
    return row[real], col[real]


@functools.cache
def _dense_solver() -> Callable[[Costs], tuple[Nodes, Nodes]]:
    """scipy's dense assignment, imported on first use (as in `match`), once: an import
    statement costs a microsecond each time, and a paper-size batch makes some thirty."""
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment


def _match_batches(
    li: Nodes, ri: Nodes, cost: Costs, alone: float, order: Nodes, cuts: Nodes
) -> tuple[list[Nodes], list[Nodes]]:
    """Exact min-cost matching of each batch of edges (`order[cuts[k]:cuts[k + 1]]`, no node in
    two batches), each node free to stay unmatched at cost `alone`: the lefts and rights taken,
    batch by batch, each batch's by left.

    Sparse LAPJVsp, one call per batch, on the graph `AugmentedBatches` describes.
    """
    from scipy.sparse.csgraph import min_weight_full_bipartite_matching  # as in `match`

    taken_l: list[Nodes] = []
    taken_r: list[Nodes] = []
    if cuts.size == 1:
        return taken_l, taken_r
    batches = AugmentedBatches.of(li, ri, cost, alone, order, cuts)
    for k in range(cuts.size - 1):
        n_l, n_r = batches.sizes(k)
        row, col = min_weight_full_bipartite_matching(batches.graph(k))
        real = (row < n_l) & (col < n_r)
        taken_l.append(batches.lefts[batches.left_start[k] + row[real]])
        taken_r.append(batches.rights[batches.right_start[k] + col[real]])
    return taken_l, taken_r


@dataclass(frozen=True)
class AugmentedBatches:
    """The graph `_match_batches` solves for each batch of edges, all built at once, in canonical
    CSR form (each row's columns ascending): a batch's own arrays are slices of these. Built
    directly: scipy's general COO -> CSR conversion and index sort, batch by batch, cost more
    than the matching itself on the small batches the associator has.

    A batch's nodes are numbered by their ids, ascending. Its rows: real lefts [0, n_l), dummies
    of rights [n_l, n_l + n_r); columns: real rights [0, n_r), dummies of lefts [n_r, n_r + n_l).
    Real left l: its edges (by right), then its own dummy n_r + l at cost `alone`; dummy of
    right r: r itself at `alone`, then the dummies of r's lefts (by left) at 0, so a full
    matching always exists. Here the batches' rows follow one another, batch by batch.
    """

    lefts: Nodes  # every batch's left nodes, batch by batch, each batch's ascending
    rights: Nodes
    left_start: Nodes  # batch k's lefts are lefts[left_start[k]:left_start[k + 1]]
    right_start: Nodes
    indptr: Nodes
    indices: Nodes
    data: Costs

    def sizes(self, k: int) -> tuple[int, int]:
        """Batch k's numbers of lefts and rights."""
        return (
            int(self.left_start[k + 1] - self.left_start[k]),
            int(self.right_start[k + 1] - self.right_start[k]),
        )

    def graph(self, k: int) -> csr_matrix:
        """Batch k's graph."""
        from scipy.sparse import csr_matrix  # on first use, as in `match`

        n_l, n_r = self.sizes(k)
        first = int(self.left_start[k] + self.right_start[k])
        rows = self.indptr[first : first + n_l + n_r + 1]
        lo, hi = int(rows[0]), int(rows[-1])
        arrays = (self.data[lo:hi], self.indices[lo:hi] - first, rows - lo)
        return csr_matrix(arrays, shape=(n_l + n_r, n_r + n_l))

    @classmethod
    def of(
        cls, li: Nodes, ri: Nodes, cost: Costs, alone: float, order: Nodes, cuts: Nodes
    ) -> AugmentedBatches:
        """The graphs of the batches of edges `order[cuts[k]:cuts[k + 1]]` (left li, right ri,
        compact ids), each node free to stay alone at cost `alone`."""
        n_batches = cuts.size - 1
        batch = np.repeat(np.arange(n_batches), np.diff(cuts))
        lefts, left_start, left_at = _batch_nodes(li[order], batch, n_batches)
        rights, right_start, right_at = _batch_nodes(ri[order], batch, n_batches)
        # All weights rounded to whole multiples of 2^-10, so that every sum LAPJVsp forms is
        # exact: with arbitrary floats its rounding errors can make it cycle forever (seen on a
        # dense block of SUMO traffic; tests/data/lapjvsp_cycle.npz). The rounding changes
        # costs by < 0.001. Then shifted, batch by batch, to at least +1: LAPJVsp needs
        # non-zero weights, and a full matching has a fixed number of edges, so the shift
        # changes nothing. (Costs are negative only where detector features make a link more
        # likely than not.)
        edge = np.round(cost[order] * COST_QUANTUM_INVERSE) / COST_QUANTUM_INVERSE
        single = float(np.round(alone * COST_QUANTUM_INVERSE) / COST_QUANTUM_INVERSE)
        shift = 1.0 - np.minimum(np.minimum.reduceat(edge, cuts[:-1]), min(0.0, single))
        # Batch k's rows (and columns) follow those of the batches before it, k's lefts' rows
        # (rights' columns) first, then its rights' dummies' rows (lefts' dummies' columns).
        left_batch = np.repeat(np.arange(n_batches), np.diff(left_start))
        right_batch = np.repeat(np.arange(n_batches), np.diff(right_start))
        left_row = np.arange(lefts.size) + right_start[left_batch]
        dummy_col = np.arange(lefts.size) + right_start[left_batch + 1]  # a left's own dummy
        right_col = np.arange(rights.size) + left_start[right_batch]
        dummy_row = np.arange(rights.size) + left_start[right_batch + 1]  # a right's own dummy
        entries = (
            (left_row[left_at], right_col[right_at], edge + shift[batch]),
            (left_row, dummy_col, single + shift[left_batch]),
            (dummy_row, right_col, single + shift[right_batch]),
            (dummy_row[right_at], dummy_col[left_at], 0.0 + shift[batch]),
        )
        # Stable (timsort): the gating gives the edges nearly by left already, so this is a
        # few times quicker than quicksort, and the keys are distinct wherever the order is used.
        by_left = np.argsort(left_at * rights.size + right_at, kind="stable")  # by left, right
        if np.any(np.diff((left_at * rights.size + right_at)[by_left]) == 0):
            arrays = _summed(entries, lefts.size + rights.size)
        else:
            arrays = _canonical(entries, (left_at, right_at), by_left)
        return cls(lefts, rights, left_start, right_start, *arrays)


def _batch_nodes(nodes: Nodes, batch: Nodes, n_batches: int) -> tuple[Nodes, Nodes, Nodes]:
    """The distinct `nodes` (compact ids, each in one batch) of each batch, batch by batch, each
    batch's ascending; where each batch starts among them (and the last ends); and the place
    of each of `nodes` among them."""
    batch_of = np.full(int(nodes.max(initial=-1)) + 1, -1)
    batch_of[nodes] = batch
    distinct = np.flatnonzero(batch_of >= 0)
    distinct = distinct[np.argsort(batch_of[distinct], kind="stable")]
    place = np.empty(batch_of.size, dtype=np.int64)
    place[distinct] = np.arange(distinct.size)
    start = np.searchsorted(batch_of[distinct], np.arange(n_batches + 1))
    return distinct, start, place[nodes]


Entries = tuple[Nodes, Nodes, Costs]


def _canonical(
    entries: tuple[Entries, Entries, Entries, Entries],
    ends: tuple[Nodes, Nodes],
    by_left: Nodes,
) -> tuple[Nodes, Nodes, Costs]:
    """`AugmentedBatches`' (indptr, indices, data), given its entries (the edges, the lefts'
    dummies, the rights' dummies, the dummies' edges) and the place of each edge's left and
    right among the lefts and rights (`ends`, edges given once, `by_left` sorting them)."""
    (edge_row, edge_col, edge_w), (left_row, dummy_col, left_w) = entries[:2]
    (dummy_row, right_col, right_w), (_, dummy_edge_col, dummy_edge_w) = entries[2:]
    left_at, right_at = ends
    n_edges = left_at.size
    degree_l = np.bincount(left_at, minlength=left_row.size)
    degree_r = np.bincount(right_at, minlength=dummy_row.size)
    size = np.empty(left_row.size + dummy_row.size, dtype=np.int64)
    size[left_row] = degree_l + 1
    size[dummy_row] = degree_r + 1
    indptr = np.zeros(size.size + 1, dtype=np.int64)
    np.cumsum(size, out=indptr[1:])
    indices = np.empty(indptr[-1], dtype=np.int64)
    data = np.empty(indptr[-1])
    # A left's row: its edges by right, then its own dummy; a right's dummy's row: the right
    # itself, then its lefts' dummies by left. A row's k-th entry sits at indptr[row] + k.
    rank = np.arange(n_edges) - (np.cumsum(degree_l) - degree_l)[left_at[by_left]]
    at = indptr[edge_row[by_left]] + rank
    indices[at] = edge_col[by_left]
    data[at] = edge_w[by_left]
    own = indptr[left_row + 1] - 1
    indices[own] = dummy_col
    data[own] = left_w
    first = indptr[dummy_row]
    indices[first] = right_col
    data[first] = right_w
    # By right, then left; distinct keys, so stable (timsort, quicker on the runs a left's
    # edges form) gives quicksort's order.
    by_right = np.argsort(right_at * left_row.size + left_at, kind="stable")
    rank = np.arange(n_edges) - (np.cumsum(degree_r) - degree_r)[right_at[by_right]]
    at = first[right_at[by_right]] + 1 + rank
    indices[at] = dummy_edge_col[by_right]
    data[at] = dummy_edge_w[by_right]
    return indptr, indices, data


def _summed(
    entries: tuple[Entries, Entries, Entries, Entries], n_rows: int
) -> tuple[Nodes, Nodes, Costs]:
    """`AugmentedBatches`' arrays where an edge is given twice: as scipy's conversion would, the
    two summed."""
    from scipy.sparse import csr_matrix  # on first use, as in `match`

    rows, cols, weights = (np.concatenate(column) for column in zip(*entries, strict=True))
    graph = csr_matrix((weights, (rows, cols)), shape=(n_rows, n_rows))
    graph.sum_duplicates()
    return graph.indptr, graph.indices, graph.data


# Node ids below this many times their number (or below COMPACT_IDS) index tables as they are.
COMPACT_FACTOR = 16
COMPACT_IDS = 4096


def _compact(nodes: Nodes) -> Nodes:
    """Small non-negative integers for the node ids, one to one: the ids themselves where they
    are such (a judged sweep's boundaries' detections), else their ranks. `chosen_marginals`
    only asks which edges share a node, which any such numbering tells alike."""
    if (
        nodes.size
        and nodes.min() >= 0
        and nodes.max() < max(COMPACT_FACTOR * nodes.size, COMPACT_IDS)
    ):
        return nodes
    return unique_inverse(nodes)[1]


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
    li, ri = _compact(left), _compact(right)
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
