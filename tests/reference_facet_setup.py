"""The oracle of the facets' and the diffuse surface's own setup (issue 36): today's node
identity, node spacing and facet tables as they were before the shared, once-computed
versions (`facet.surface.merge_nodes`, `node_spacing`; `PatchedSurface` sharing them with its
facets and its patches' surfaces). Pure numpy/scipy, kept out of the package;
tests/test_facet_setup_fast.py compares the package with it, bit for bit."""
from __future__ import annotations

import numpy as np

from diffsurf_cli import tol
from diffsurf_cli.facet import _engine
from diffsurf_cli.mls import _search
from diffsurf_cli.mls import frame as _frame


def merge(nodes: np.ndarray):
    """facet.surface._merge as it was: (first, distinct, group) by a stable lexsort."""
    order = np.lexsort(nodes.T[::-1])
    s = nodes[order]
    new = np.ones(len(nodes), bool)
    new[1:] = np.any(s[1:] != s[:-1], axis=1)
    distinct = order[new]
    group = np.empty(len(nodes), dtype=np.int64)
    group[order] = np.cumsum(new) - 1
    return distinct[group], distinct, group


def node_identity(nodes: np.ndarray) -> np.ndarray:
    """patches.segment.node_identity as PatchedSurface.__init__ called it (np.unique)."""
    _, first, inverse = np.unique(nodes, axis=0, return_index=True, return_inverse=True)
    return first[inverse.ravel()]


def facet_spacing(nodes: np.ndarray) -> np.ndarray:
    """FacetSurface's node spacing as it was: cKDTree over the distinct positions."""
    from scipy.spatial import cKDTree

    _, distinct, group = merge(nodes)
    pts = nodes[distinct]
    k = min(tol.SPACING_NEIGHBOURS + 1, len(pts))
    dist, _ = cKDTree(pts).query(pts, k=k, workers=-1)
    return dist[:, 1:].mean(axis=1)[group]


def tune_spacing(nodes: np.ndarray) -> np.ndarray:
    """tune.node_spacing as it was (no merging: tune merges its nodes before)."""
    from scipy.spatial import cKDTree

    k = min(tol.SPACING_NEIGHBOURS + 1, len(nodes))
    dist, _ = cKDTree(nodes).query(nodes, k=k)
    return dist[:, 1:].mean(axis=1)


def diffuse_setup(nodes, faces, flip=False) -> dict:
    """DiffuseSurface.__init__'s node tables as they were (np.unique, the grid's spacing)."""
    nodes = np.asarray(nodes, dtype=np.float64)
    _, first, inverse = np.unique(nodes, axis=0, return_index=True, return_inverse=True)
    out = {"first": first[inverse.ravel()], "duplicates": len(first) < len(nodes)}
    n = len(first)
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    normals = _frame.node_normals(nodes, [out["first"][f] for f in faces])[out["first"]]
    if flip:
        normals = -normals
    out["normals"] = normals
    distinct = nodes[first]
    k = min(tol.SPACING_NEIGHBOURS + 1, n)
    dist = _search.nearest_distances(distinct, k)
    out["node_spacing"] = dist.reshape(n, -1)[:, 1:].mean(axis=1)[inverse.ravel()]
    out["origin"], out["axes"] = _frame.mean_plane(distinct, normals[first] if faces else None)
    if flip and not faces:
        out["axes"] = out["axes"] * np.array([[1.0], [-1.0], [-1.0]])
    signed = np.any(normals != 0, axis=1)
    out["signed"] = signed
    out["fold_normals"] = normals
    if not signed.all():
        out["fold_normals"] = np.where(signed[:, None], normals,
                                       _frame.pca_normals(distinct)[inverse.ravel()])
    planar = (distinct - distinct.mean(axis=0)) @ out["axes"][:2].T
    spread = np.linalg.eigvalsh(planar.T @ planar)
    out["ruled"] = bool(spread[0] >= tol.RULED_SPREAD * spread[1] and spread[1] > 0)
    out["distinct_count"] = len(np.unique(nodes, axis=0))  # patches' _fewer_terms
    return out


def tables(nodes, canon, facets, sign, ctol) -> dict:
    """facet.surface._tables as it was."""
    n, F = len(nodes), len(facets)
    used = np.zeros(n, bool)
    used[facets[facets >= 0]] = True
    lo, hi = nodes[used].min(axis=0), nodes[used].max(axis=0)
    centre = 0.5 * (lo + hi)
    X = nodes - centre
    radius = float(np.sqrt((X[used] ** 2).sum(axis=1).max()))
    kind = np.where(facets[:, 3] < 0, 3, 4).astype(np.int64)
    corner = X[np.where(facets >= 0, facets, facets[:, :1])]
    centroid = corner.mean(axis=1)
    order, box, link = _engine.build_hierarchy(
        np.ascontiguousarray(np.concatenate([corner.min(axis=1), corner.max(axis=1)], axis=1)),
        np.ascontiguousarray(centroid))
    slot = np.empty(F, dtype=np.int64)
    slot[order] = np.arange(F)
    corner = np.ascontiguousarray(corner[order])
    kind, facets = kind[order], facets[order]
    fnode = np.ascontiguousarray(np.where(facets >= 0, canon[np.maximum(facets, 0)], -1))
    vnormal = np.zeros((n, 3))
    fnormal = np.empty((F, 3))
    _engine.corner_normals(corner, kind, fnode, vnormal, fnormal)
    tri = (kind == 3)[:, None]
    b = np.where(tri, fnode[:, [1, 2, 0, 0]], fnode[:, [1, 2, 3, 0]])
    real = np.arange(4)[None, :] < kind[:, None]
    key = (np.minimum(fnode, b) * n + np.maximum(fnode, b))[real]
    inc = (4 * np.arange(F)[:, None] + np.arange(4)[None, :])[real]
    by_edge = np.argsort(key, kind="stable")
    new = np.ones(len(key), bool)
    new[1:] = key[by_edge][1:] != key[by_edge][:-1]
    edge = np.empty(len(key), dtype=np.int64)
    edge[by_edge] = np.cumsum(new) - 1
    fedge = np.full((F, 4), -1, dtype=np.int64)
    fedge[real] = edge
    edge_ptr = np.append(np.flatnonzero(new), len(key)).astype(np.int64)
    norm = np.linalg.norm(vnormal, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        vunit = np.where(norm > 0, vnormal / norm, 0.0)
    # the hierarchy's oriented bounds: the engine's own function (what they must hold, every
    # corner of their facets, is checked on its own: tests/test_oriented_bounds.py)
    cyl = _engine.oriented_bounds(corner, np.ascontiguousarray(kind, dtype=np.int8), link)
    return {"corner": corner, "kind": kind, "fnormal": fnormal, "fnode": fnode,
            "fedge": fedge, "edge_ptr": edge_ptr,
            "edge_inc": np.ascontiguousarray(inc[by_edge], dtype=np.int64),
            "vnormal": np.ascontiguousarray(vunit), "box": box, "link": link, "cyl": cyl,
            "ctol": np.ascontiguousarray(ctol, dtype=np.float64), "original": order,
            "slot": slot, "centre": np.ascontiguousarray(centre), "radius": max(radius, tol.TINY),
            "sign": float(sign), "quad_iterations": tol.QUAD_ITERATIONS,
            "quad_step": tol.QUAD_STEP, "edge_eps": tol.EDGE_EPS, "far": tol.FAR_RADII,
            "proxy": tol.PROXY_RADII}


def facet_geometry(nodes, facets, flip=False) -> tuple:
    """FacetSurface._geometry as it was: (node_spacing, tables) of a (F, 4) facet table."""
    nodes = np.asarray(nodes, dtype=np.float64)
    first, _, _ = merge(nodes)
    spacing = facet_spacing(nodes)
    return spacing, tables(nodes, first, facets, -1.0 if flip else 1.0,
                           tol.CONTACT * spacing)
