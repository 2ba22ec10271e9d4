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


def sample_cylinder_points(m, rng):
    """m points around the sample cylinder (sample_meshes/cylinder.msh: radius 10, axis z
    through (32.5, 30), its lower half, z from -2.5 to 7.5) away from its open edges, within
    1 of its radius; returns (points, exact gap): the offset from the radius."""
    theta = rng.uniform(np.pi + 0.2, 2 * np.pi - 0.2, m)
    offset = rng.uniform(-1.0, 1.0, m)
    r = 10 + offset
    return np.column_stack([32.5 + r * np.cos(theta), 30 + r * np.sin(theta),
                            rng.uniform(-1.5, 6.5, m)]), offset
