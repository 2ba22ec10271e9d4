"""The same polyhedron cut finer (issue 34): facets split at their centroid, quads cut into
four or into four triangles. Every new node lies on a chord or in a facet's plane: no new
geometry, what `patches.segment.geometry_free` must find. For the tests and
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
