"""The oracle of `projection.inside_out` (issue 36): the former code, whose closed edges were
found by numpy's masks and gathers over the edges (now one compiled pass,
`patches._edges.closed_pairs`). tests/test_inside_out_fast.py compares them."""
from __future__ import annotations

import numpy as np

from diffsurf_cli.projection import bounds


def inside_out(nodes, faces, ident=None, edges=None) -> tuple[int, float]:
    """The closed surfaces of a target wound inside out: (facets, volume) of those of its
    connected surfaces that are closed and consistently wound (every edge run once each way
    by two facets; coincident nodes are one node) and enclose a negative volume (the
    divergence theorem: sum over facets of x0 . (x1 x x2) / 6), unless they lie within the box
    of a closed surface of positive volume (a cavity of a hollow body, a thin shell's inner
    wall, rightly wound into the void). Open surfaces have no inside and count for nothing.
    Linear in the facets (the edges' compiled pass, `patches.segment.edge_table`).

    nodes : (n, 3) float; faces : facet blocks as `as_faces` returns them; ident : (n,) int,
    optional: the first node at each node's position (computed when not given); edges :
    optional, the facet edges (`patches.segment.edge_table` of `faces` by `ident`) where the
    caller has them (`PatchedSurface`), computed when not given."""
    from diffsurf_cli.facet import _setup
    from diffsurf_cli.patches import segment as _segment

    blocks = [np.asarray(f)[:, :4 if f.shape[1] in (4, 8, 9) else 3] for f in faces if len(f)]
    if not blocks:
        return 0, 0.0
    F = sum(len(f) for f in blocks)
    if edges is None:
        if ident is None:
            ident = _segment.node_identity(nodes)
        edges = _segment.edge_table(blocks, np.asarray(ident).ravel())
    fac, edge = edges.fac, edges.edge
    # an edge of two facets running it opposite ways (one half-edge from its smaller node
    # identity to its larger) joins them; any other edge (open, non-manifold, or run the same
    # way twice) leaves its facets' surface unclosed
    # (an edge of two half-edges, `forward` 0 or 1 each: run both ways where they differ)
    two = np.diff(edges.start) == 2
    at = edges.start[:-1][two]
    h0, h1 = edges.order[at], edges.order[at + 1]  # the two half-edges of each, by edge
    del at
    way = edges.forward[h0] != edges.forward[h1]
    good = np.zeros(edges.ne, bool)
    good[two] = way
    comp = _segment.components(F, fac[h0[way]], fac[h1[way]])
    del h0, h1, way, two
    open_comp = np.zeros(comp.max() + 1, bool)
    open_comp[comp[fac[~good[edge]]]] = True
    # enclosed volume per surface, about the centre of the nodes (round-off of far meshes):
    # six times each facet's, one compiled pass a block (x0 . (x1 x x2), plus x0 . (x2 x x3)
    # for a quad, as numpy's einsum of np.cross summed them: the same volumes bit for bit)
    x = np.asarray(nodes, dtype=np.float64)
    lo, hi = bounds(x)
    x = np.ascontiguousarray(x - 0.5 * (lo + hi))
    vol = np.concatenate([_setup.facet_volumes(x, np.asarray(f, dtype=np.int64))
                          for f in blocks])
    volume = np.bincount(comp, weights=vol / 6.0)
    del vol
    bad = ~open_comp & (volume < 0)
    outer = np.flatnonzero(~open_comp & (volume > 0))
    if bad.any() and len(outer):  # a cavity: inside the box of a body wound outward
        corners = np.concatenate([np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1)
                                  for f in blocks])
        ncomp = len(volume)
        lo = np.full((ncomp, 3), np.inf)
        hi = np.full((ncomp, 3), -np.inf)
        at = np.repeat(comp, 4)[corners.ravel() >= 0]
        pts = x[corners.ravel()[corners.ravel() >= 0]]
        np.minimum.at(lo, at, pts)
        np.maximum.at(hi, at, pts)
        for c in np.flatnonzero(bad):
            if np.any(np.all(lo[outer] <= lo[c], axis=1) & np.all(hi[outer] >= hi[c], axis=1)):
                bad[c] = False
    return int(bad[comp].sum()), float(volume[bad].sum())
