"""The same polyhedron cut finer (issue 34): facets split at their centroid, quads cut into
four or into four triangles. Every new node lies on a chord or in a facet's plane: no new
geometry, what `patches.segment.geometry_free` must find; second-order cells cut in four on
their own map (`refine_on_map`), the new nodes on the curved cells. For the tests and
benchmarks/refinement.py."""
from __future__ import annotations

import numpy as np


def split_centroids(nodes, faces, count=30, seed=0):
    """`count` triangles (seeded) split at their centroid into three: (nodes, triangles)."""
    nodes, faces = np.asarray(nodes, float), np.asarray(faces)
    pick = np.random.default_rng(seed).choice(len(faces), count, replace=False)
    extra = np.arange(len(nodes), len(nodes) + count)
    a, b, c = faces[pick].T
    cut = np.concatenate([np.column_stack(t) for t in ((a, b, extra), (b, c, extra),
                                                       (c, a, extra))])
    return (np.vstack([nodes, nodes[faces[pick]].mean(axis=1)]),
            np.vstack([np.delete(faces, pick, axis=0), cut]))


def refine_quads(nodes, quads):
    """Each quad into four: its edges' middles and its centre, on the chords."""
    nodes, index = [tuple(x) for x in nodes], {}

    def middle(*ids):
        k = tuple(sorted(ids))
        if k not in index:
            index[k] = len(nodes)
            nodes.append(tuple(np.mean([nodes[i] for i in ids], axis=0)))
        return index[k]

    out = []
    for a, b, c, d in quads:
        ab, bc, cd, da = middle(a, b), middle(b, c), middle(c, d), middle(d, a)
        m = middle(a, b, c, d)
        out += [[a, ab, m, da], [ab, b, bc, m], [m, bc, c, cd], [da, m, cd, d]]
    return np.array(nodes), np.array(out)


def quads_to_triangles(nodes, quads):
    """Each quad into four triangles around its centre."""
    nodes, quads = np.asarray(nodes, float), np.asarray(quads)
    centre = np.arange(len(nodes), len(nodes) + len(quads))
    tri = [np.column_stack([quads[:, j], quads[:, (j + 1) % 4], centre]) for j in range(4)]
    return np.vstack([nodes, nodes[quads].mean(axis=1)]), np.vstack(tri)


def sample_cylinder_points(m, rng):
    """m points around the sample cylinder (sample_meshes/cylinder.msh: radius 10, axis z
    through (32.5, 30), its lower half, z from -2.5 to 7.5) away from its open edges, within
    1 of its radius; returns (points, exact gap): the offset from the radius."""
    theta = rng.uniform(np.pi + 0.2, 2 * np.pi - 0.2, m)
    offset = rng.uniform(-1.0, 1.0, m)
    r = 10 + offset
    return np.column_stack([32.5 + r * np.cos(theta), 30 + r * np.sin(theta),
                            rng.uniform(-1.5, 6.5, m)]), offset


#: The parameters of a second-order cell's nodes (gmsh's order): triangle6 on the unit
#: triangle, quad8 and quad9 on [-1, 1]² (a quad's centre last)
_PARAM = {6: [(0, 0), (1, 0), (0, 1), (.5, 0), (.5, .5), (0, .5)],
          8: [(-1, -1), (1, -1), (1, 1), (-1, 1), (0, -1), (1, 0), (0, 1), (-1, 0), (0, 0)]}
_PARAM[9] = _PARAM[8]
#: Each cell's four children (gmsh's order), the corners of each by the parent's nodes
_CHILDREN = {6: [(0, 3, 5), (3, 1, 4), (5, 4, 2), (3, 4, 5)],
             8: [(0, 4, 8, 7), (4, 1, 5, 8), (8, 5, 2, 6), (7, 8, 6, 3)]}
_CHILDREN[9] = _CHILDREN[8]


def second_order_shape(w, a, b):
    """(w,) the shape functions of a triangle6 (w = 6), quad8 or quad9 at (a, b)."""
    if w == 6:
        c = 1 - a - b
        return np.array([c * (2 * c - 1), a * (2 * a - 1), b * (2 * b - 1), 4 * c * a, 4 * a * b,
                         4 * b * c])
    if w == 9:
        def lag(s):  # the quadratics through -1, 0, 1
            return {-1: s * (s - 1) / 2, 0: 1 - s * s, 1: s * (s + 1) / 2}

        la, lb = lag(a), lag(b)
        return np.array([la[p] * lb[q] for p, q in _PARAM[9]])
    out = []
    for p, q in _PARAM[8][:8]:
        if p and q:
            out.append((1 + a * p) * (1 + b * q) * (a * p + b * q - 1) / 4)
        elif p == 0:
            out.append((1 - a * a) * (1 + b * q) / 2)
        else:
            out.append((1 + a * p) * (1 - b * b) / 2)
    return np.array(out)


def refine_on_map(nodes, cells, move=None):
    """Each triangle6, quad8 or quad9 of `cells` (one block) cut into four of its type on its
    own map: the new nodes are the parent's map at the children's parameters (on the curved
    cell); `move` (optional, (k, 3) -> (k, 3)) then moves them (onto the CAD, as a mesher
    would: new geometry). Returns (nodes, cells)."""
    from scipy.spatial import cKDTree

    nodes, cells = np.asarray(nodes, float), np.asarray(cells)
    w = cells.shape[1]
    param = np.array(_PARAM[w], float)
    points, children, total = [nodes], [], len(nodes)
    for child in _CHILDREN[w]:
        xi = param[list(child)]
        at = [xi, (xi + np.roll(xi, -1, axis=0)) / 2]
        if w == 9:
            at.append(xi.mean(axis=0, keepdims=True))
        ids = np.empty((len(cells), w), np.int64)
        for j, p in enumerate(np.concatenate(at)):
            own = [k for k in range(w) if np.allclose(param[k], p)]
            if own:  # a node of the parent
                ids[:, j] = cells[:, own[0]]
            else:
                points.append(nodes[cells].transpose(0, 2, 1) @ second_order_shape(w, *p))
                ids[:, j] = np.arange(total, total + len(cells))
                total += len(cells)
        children.append(ids)
    points = np.vstack(points)
    # one node per point: a new point on a side two parents share is made by both
    first = np.arange(total)
    scale = float(np.linalg.norm(np.ptp(nodes, axis=0)))
    for i, j in sorted(cKDTree(points).query_pairs(1e-9 * scale)):
        first[max(i, j)] = first[min(i, j)]
    keep = np.unique(first)
    renum = np.searchsorted(keep, first)
    points = points[keep]
    if move is not None:
        new = np.arange(np.searchsorted(keep, len(nodes)), len(keep))
        points[new] = move(points[new])
    return points, np.vstack([renum[c] for c in children])
