"""The numpy topology tables that `diffsurf_cli.patches._topology` is checked against (issue 36).

Verbatim copies of the package's implementations before the compiled pass: the facet edges and
node identity (`patches.segment`), the segmentation with its flat faces and open nodes,
`PatchedSurface._classify_edges` and `PatchedSurface._rings` (as functions of a surface's
attributes), and `projection.inside_out`. Each returns what the package's stored then.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from diffsurf_cli import tol
from diffsurf_cli.mls import frame as _frame
from diffsurf_cli.patches.surface import INSIDE, OPEN_EDGE, SHARP, SMOOTH, _regions


def facet_edges(faces, node_key):
    fac, loc, a, b = [], [], [], []
    start = 0
    for f in faces:
        f = _frame.facet_corners(f)
        k = f.shape[1]
        for j in range(k):
            fac.append(start + np.arange(len(f)))
            loc.append(np.full(len(f), j))
            a.append(node_key[f[:, j]])
            b.append(node_key[f[:, (j + 1) % k]])
        start += len(f)
    if not fac:
        z = np.zeros(0, np.int64)
        return z, z, z, 0
    fac, loc, a, b = (np.concatenate(x).astype(np.int64) for x in (fac, loc, a, b))
    n = int(max(a.max(), b.max())) + 1
    key = np.minimum(a, b) * n + np.maximum(a, b)
    uniq, edge = np.unique(key, return_inverse=True)
    return fac, loc, edge.ravel(), len(uniq)


def node_identity(nodes):
    _, first, inverse = np.unique(nodes, axis=0, return_index=True, return_inverse=True)
    return first[inverse.ravel()]


def segment(nodes, faces, feature_angle=40.0, tags=None, flat_faces=True, smooth_tags=False):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nodes = np.asarray(nodes, dtype=np.float64)
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        faces = [faces]
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    nf = sum(len(f) for f in faces)
    if nf == 0:
        return np.zeros(0, np.int64)
    fac, _, edge, ne = facet_edges(faces, node_identity(nodes))
    area = _frame.facet_area_vectors(nodes, faces)
    top = np.abs(area).max(axis=1, keepdims=True)
    unit = np.divide(area, top, out=np.zeros_like(area), where=top > 0)
    norm = np.linalg.norm(unit, axis=1, keepdims=True)
    unit = np.divide(unit, norm, out=np.zeros_like(unit), where=norm > 0)
    order = np.argsort(edge, kind="stable")
    e, f = edge[order], fac[order]
    count = np.bincount(e, minlength=ne)
    two = count[e] == 2
    first = np.ones(len(e), bool)
    first[1:] = e[1:] != e[:-1]
    i = np.flatnonzero(first & two)
    fa, fb = f[i], f[i + 1]
    join = fa != fb
    if tags is not None:
        tags = np.asarray(tags).reshape(-1)
        if len(tags) != nf:
            raise ValueError(f"{len(tags)} facet tags for {nf} facets")
    if feature_angle < 180:
        cos = np.einsum("ij,ij->i", unit[fa], unit[fb])
        smooth = cos >= np.cos(np.radians(feature_angle))
        # issue 35: nor the bends of coarse smooth curves (the rule: tests/test_creases.py)
        from diffsurf_cli.patches.segment import creases
        smooth |= ~creases(nodes, faces, feature_angle)[e[i]]
        if smooth_tags and tags is not None:
            smooth |= tags[fa] == tags[fb]
        join &= smooth
    if tags is not None:
        join &= tags[fa] == tags[fb]
    if flat_faces:
        flat = _flat_faces(nodes, faces, fa, fb, unit)
        join &= flat[fa] == flat[fb]
    graph = coo_matrix((np.ones(int(join.sum())), (fa[join], fb[join])), shape=(nf, nf))
    _, label = connected_components(graph, directed=False)
    _, firsts, inverse = np.unique(label, return_index=True, return_inverse=True)
    rank = np.empty(len(firsts), np.int64)
    rank[np.argsort(firsts, kind="stable")] = np.arange(len(firsts))
    return rank[inverse.ravel()]


def _flat_faces(nodes, faces, fa, fb, unit):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    nf = len(unit)
    same = np.einsum("ij,ij->i", unit[fa], unit[fb]) >= tol.FLAT_COS
    graph = coo_matrix((np.ones(int(same.sum())), (fa[same], fb[same])), shape=(nf, nf))
    _, comp = connected_components(graph, directed=False)
    fnode, fcomp = [], []
    start = 0
    for f in faces:
        c = _frame.facet_corners(f)
        fnode.append(c.ravel())
        fcomp.append(np.repeat(comp[start:start + len(c)], c.shape[1]))
        start += len(c)
    key = node_identity(nodes)
    fnode = key[np.concatenate(fnode)]
    fcomp = np.concatenate(fcomp)
    n = len(nodes)
    lo = np.full(n, np.iinfo(np.int64).max)
    hi = np.full(n, -1)
    np.minimum.at(lo, fnode, fcomp)
    np.maximum.at(hi, fnode, fcomp)
    inner = (hi >= 0) & (lo == hi) & ~_open_nodes(faces, key, n)
    has_inner = np.zeros(nf, bool)
    has_inner[np.unique(lo[inner])] = True
    sizes = np.bincount(comp, minlength=nf)
    return np.where(has_inner[comp] & (sizes[comp] > 1), comp, -1)


def _open_nodes(faces, key, n):
    fac, loc, edge, ne = facet_edges(faces, key)
    count = np.bincount(edge, minlength=ne)
    blocks = [_frame.facet_corners(f) for f in faces]
    corners = np.concatenate([np.pad(c, ((0, 0), (0, 4 - c.shape[1])), constant_values=-1)
                              for c in blocks])
    kind = np.where(corners[:, 3] < 0, 3, 4)
    one = count[edge] == 1
    a = corners[fac[one], loc[one]]
    b = corners[fac[one], (loc[one] + 1) % kind[fac[one]]]
    out = np.zeros(n, bool)
    out[key[a]] = True
    out[key[b]] = True
    return out


def classify_edges(surf, faces):
    """`PatchedSurface._classify_edges` on `surf` (its key, label, corners, kind, nodes,
    facet_normal, feature_angle, smooth_tags, tags): a namespace of edge_class,
    vertex_class, edge_facets, edge_sharp, smooth_region."""
    out = SimpleNamespace()
    fac, loc, edge, ne = facet_edges(faces, surf.key)
    count = np.bincount(edge, minlength=ne)
    lo = np.full(ne, np.iinfo(np.int64).max)
    hi = np.full(ne, -1)
    np.minimum.at(lo, edge, surf.label[fac])
    np.maximum.at(hi, edge, surf.label[fac])
    flo = np.full(ne, np.iinfo(np.int64).max)
    fhi = np.full(ne, -1)
    np.minimum.at(flo, edge, fac)
    np.maximum.at(fhi, edge, fac)
    two = count == 2
    cos = np.ones(ne)
    cos[two] = np.einsum("ij,ij->i", surf.facet_normal[flo[two]], surf.facet_normal[fhi[two]])
    angle = 180.0 if surf.feature_angle is None else min(surf.feature_angle, 180.0)
    sharp = cos < np.cos(np.radians(angle))
    if surf.smooth_tags:
        same_tag = np.zeros(ne, bool)
        same_tag[two] = surf.tags[flo[two]] == surf.tags[fhi[two]]
        sharp &= ~same_tag
    cls = np.where(~two, OPEN_EDGE, np.where(sharp, SHARP, np.where(lo == hi, INSIDE,
                                                                     SMOOTH)))
    cls = cls.astype(np.int8)
    out.edge_class = np.zeros((len(surf.corners), 4), np.int8)
    out.edge_class[fac, loc] = cls[edge]
    vertex_class = np.zeros(len(surf.nodes), np.int8)
    a = surf.corners[fac, loc]
    b = surf.corners[fac, np.where(loc + 1 < surf.kind[fac], loc + 1, 0)]
    for end in (a, b):
        np.maximum.at(vertex_class, surf.key[end], cls[edge])
    out.vertex_class = vertex_class[surf.key]
    out.edge_facets = np.stack([flo[two], fhi[two]], axis=1)
    out.edge_sharp = sharp[two]
    out.smooth_region = _regions(len(surf.corners), out.edge_facets[~out.edge_sharp])
    return out


def rings(surf):
    """`PatchedSurface._rings` on `surf` (corners, key, nodes, npatches, label): a namespace of
    ring (scipy CSR), ring_ptr, ring_patches."""
    from scipy.sparse import csr_matrix

    out = SimpleNamespace()
    F = len(surf.corners)
    fac = np.repeat(np.arange(F), 4)
    node = surf.corners.ravel()
    real = node >= 0
    incidence = csr_matrix((np.ones(int(real.sum())), (fac[real], surf.key[node[real]])),
                           shape=(F, len(surf.nodes)))
    ring = (incidence @ incidence.T).tocsr()
    ring.sort_indices()
    out.ring = ring
    rows = np.repeat(np.arange(F), np.diff(ring.indptr))
    pairs = np.unique(rows * np.int64(surf.npatches) + surf.label[ring.indices])
    owner = pairs // surf.npatches
    out.ring_ptr = np.searchsorted(owner, np.arange(F + 1)).astype(np.int64)
    out.ring_patches = (pairs % surf.npatches).astype(np.int64)
    return out


def inside_out(nodes, faces, ident=None):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    blocks = [np.asarray(f)[:, :4 if f.shape[1] in (4, 8, 9) else 3] for f in faces if len(f)]
    if not blocks:
        return 0, 0.0
    corners = np.concatenate([np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1)
                              for f in blocks])
    F = len(corners)
    kind = np.where(corners[:, 3] < 0, 3, 4)
    if ident is None:
        _, ident = np.unique(nodes, axis=0, return_inverse=True)
    ident = np.asarray(ident).ravel().astype(np.int64)
    n = int(ident.max()) + 1
    nxt = np.where(np.arange(4)[None] + 1 < kind[:, None], np.arange(1, 5)[None] % 4, 0)
    real = np.arange(4)[None] < kind[:, None]
    a = ident[np.maximum(corners, 0)][real]
    b = ident[corners[np.arange(F)[:, None], nxt]][real]
    fac = np.repeat(np.arange(F), kind)
    key = np.minimum(a, b) * n + np.maximum(a, b)
    uniq, edge, count = np.unique(key, return_inverse=True, return_counts=True)
    edge = edge.ravel()
    forward = (a < b).astype(np.int64)
    ways = np.bincount(edge, weights=forward, minlength=len(uniq))
    good = (count == 2) & (ways == 1)
    order = np.argsort(edge, kind="stable")
    ends = np.flatnonzero(good[edge[order]])
    first = ends[::2]
    f1, f2 = fac[order[first]], fac[order[first + 1]]
    _, comp = connected_components(coo_matrix((np.ones(len(f1)), (f1, f2)), shape=(F, F)),
                                   directed=False)
    open_comp = np.zeros(comp.max() + 1, bool)
    open_comp[comp[fac[~good[edge]]]] = True
    x = np.asarray(nodes, dtype=np.float64)
    x = x - 0.5 * (x.min(axis=0) + x.max(axis=0))
    c = x[np.maximum(corners, 0)]
    vol = np.einsum("fi,fi->f", c[:, 0], np.cross(c[:, 1], c[:, 2]))
    quad = kind == 4
    vol[quad] += np.einsum("fi,fi->f", c[quad, 0], np.cross(c[quad, 2], c[quad, 3]))
    volume = np.bincount(comp, weights=vol / 6.0)
    bad = ~open_comp & (volume < 0)
    outer = np.flatnonzero(~open_comp & (volume > 0))
    if bad.any() and len(outer):
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
