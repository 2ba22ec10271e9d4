"""A target's nodes as every surface measures them: their identity (exact duplicates merged)
and their local spacing h, measured once and shared by the facets (`facet.surface`), the
diffuse surface (`mls.surface`) and `tune`; and the row norms they use. Below both methods:
the facets do not import the diffuse method (tests/test_layout.py); the nearest-node search is
the compiled grid's (`mls._search`, a search structure, not the diffuse method)."""
from __future__ import annotations

import numpy as np

from . import tol
from .mls import _search


def merge_nodes(nodes: np.ndarray):
    """Exact duplicates: (first (n,) the first node at each node's position, distinct (d,) the
    first of each position, group (n,) each node's position in `distinct`)."""
    order = np.lexsort(nodes.T[::-1])  # stable: a position's first node comes first
    s = nodes[order]
    new = np.ones(len(nodes), bool)
    new[1:] = np.any(s[1:] != s[:-1], axis=1)
    distinct = order[new]
    group = np.empty(len(nodes), dtype=np.int64)
    group[order] = np.cumsum(new) - 1
    return distinct[group], distinct, group


def node_spacing(nodes: np.ndarray, merged=None) -> np.ndarray:
    """(n,) local node spacing h: the mean distance of each node to its
    `tol.SPACING_NEIGHBOURS` (4) nearest distinct positions (exact duplicates merged,
    `merge_nodes`), a function of the geometry only: the one measure of the facets, the diffuse
    surface and `tune`. The grid's exact search (`mls._search.nearest_distances`: the
    distances scipy's cKDTree gives, value for value; tie-breaks do not enter a distance).
    `merged`: `merge_nodes(nodes)` when the caller has it."""
    _, distinct, group = merge_nodes(nodes) if merged is None else merged
    d = len(distinct)
    k = min(tol.SPACING_NEIGHBOURS + 1, d)
    dist = _search.nearest_distances(nodes[distinct], k)
    return dist.reshape(d, -1)[:, 1:].mean(axis=1)[group]


class SharedNodes:
    """A target's node identity and node spacing, measured once and shared by the surfaces
    built on the same nodes (`PatchedSurface`: its node identity `key`, its whole target's
    `FacetSurface` and, for one patch, its `DiffuseSurface`; each patch's facets and surface).

    Attributes
    ----------
    nodes : (n, 3) float
    first : (n,) int     the first node at each node's position (the node identity)
    distinct : (d,) int  the first node of each position, positions in lexicographic order
                         (np.unique's order: the diffuse surface's mean plane sums them so)
    group : (n,) int     each node's position in `distinct`
    spacing : (n,) float `node_spacing`, measured on first use
    """

    def __init__(self, nodes: np.ndarray, merged=None):
        self.nodes = nodes
        self.first, self.distinct, self.group = merge_nodes(nodes) if merged is None else merged
        self._spacing = None

    @classmethod
    def of(cls, nodes: np.ndarray, shared=None) -> SharedNodes:
        """`shared` where it was measured on these very nodes (the same array, or equal
        values), else the nodes' own."""
        if shared is not None and (shared.nodes is nodes or (
                shared.nodes.shape == nodes.shape and np.array_equal(shared.nodes, nodes))):
            return shared
        return cls(nodes)

    @property
    def spacing(self) -> np.ndarray:
        if self._spacing is None:
            self._spacing = node_spacing(self.nodes, (self.first, self.distinct, self.group))
        return self._spacing

    def subset(self, used: np.ndarray) -> SharedNodes:
        """The identity of the nodes `used` (ascending indices; a patch's nodes), from this
        one's: positions keep their lexicographic rank (`group`), so a stable sort of the
        ranks is `merge_nodes`'s lexsort of the subset's coordinates, without the float compares.
        Their spacing is their own (a subset's nearest nodes are not the target's)."""
        rank = self.group[used]
        order = np.argsort(rank, kind="stable")
        new = np.ones(len(used), bool)
        new[1:] = rank[order][1:] != rank[order][:-1]
        distinct = order[new]
        group = np.empty(len(used), dtype=np.int64)
        group[order] = np.cumsum(new) - 1
        return SharedNodes(self.nodes[used], (distinct[group], distinct, group))


def row_norms(v: np.ndarray) -> np.ndarray:
    """(f,) the Euclidean norm of each row of v (f, 3): ``np.linalg.norm(v, axis=1)`` bit for
    bit (its sum of squares is (x² + y²) + z², as numpy's reduction over a row of three),
    column by column instead of a reduction along the short axis (several times faster)."""
    v = np.asarray(v, dtype=np.float64)
    return np.sqrt((v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]) + v[:, 2] * v[:, 2])
