"""Segmentation of a target into smooth patches (method.md "Real targets: patches").

Facets are in one patch when they share an edge whose dihedral angle (between the facet
normals) is below the feature angle and carry the same face or region tag (a Gmsh entity, a
physical group, a cell set) where the file has tags, and neither or both are on one flat face
(so a file without tags, an STL, still gets its flat faces exact, apart from the fillets they
meet tangentially). An edge of one facet (an open boundary), or of more than two (a T
junction), joins nothing. Facets are taken by their corners (higher-order cells:
`frame.facet_corners`); the node identity, the edges and the groups of facets come from
linear compiled passes (`_topology.pyx`), the rest is numpy.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .. import tol
from ..mls import frame as _frame
from . import _edges, _topology

#: Default feature angle, degrees: edges whose facets' normals differ by more split patches.
#: Measured (`python benchmarks/feature_targets.py --angles`): the largest facet-to-facet
#: angle of smooth targets is 11.3° (sample cylinder), 23.4° (sample torus), 22.1° (gmsh
#: sphere at 2 elements per radius), 25.2° (side of a gmsh cylinder at 1.7 elements per
#: radius); CAD edges are 45° (chamfers) to 90° (boxes) and more. 40° sits between, with room
#: for coarser curved meshes (a cylinder of 9 facets around meets at 40°).
FEATURE_ANGLE_DEG = 40.0


class Edges(NamedTuple):
    """The facet edges of a target (`edge_table`): every corner edge of every facet (a
    half-edge), by facet, local edge and edge; computed once and shared by the winding check,
    the segmentation and the edges' classes."""

    fac: np.ndarray      # (e,) facet of each half-edge
    loc: np.ndarray      # (e,) its local edge j: from corner j to corner j + 1
    edge: np.ndarray     # (e,) its edge: edges numbered by their ends' (smaller, larger) identity
    ne: int              # the number of distinct edges
    order: np.ndarray    # (e,) the half-edges by edge, stable (argsort(edge, kind="stable"))
    start: np.ndarray    # (ne + 1,) edge i's half-edges are order[start[i]:start[i + 1]]
    ends: np.ndarray     # (ne, 2) its ends' identities, smaller first
    forward: np.ndarray  # (e,) int8: the half-edge runs from the smaller identity to the larger


class FacetRing(NamedTuple):
    """The vertex ring of each facet (`PatchedSurface.ring`): the facets sharing a node with
    it, itself included, as CSR rows sorted within (the compiled pass's fring_ptr, fring)."""

    indptr: np.ndarray   # (F + 1,) int32
    indices: np.ndarray  # int32


def edge_table(faces: list[np.ndarray], node_key: np.ndarray) -> Edges:
    """The facet edges (`Edges`) of facet blocks `faces` (facets numbered block after block,
    taken by their corners), `node_key` mapping nodes to their identity (coincident nodes
    share one): one compiled pass and two counting sorts, linear in the facets."""
    blocks = [np.ascontiguousarray(_frame.facet_corners(f), dtype=np.int64) for f in faces]
    return Edges(*_topology.edge_table(blocks, np.ascontiguousarray(node_key, dtype=np.int64)))


def facet_edges(faces: list[np.ndarray], node_key: np.ndarray):
    """Every corner edge of every facet: (facet (e,), local edge j (e,), edge id (e,), number
    of distinct edges). Edge j runs from corner j to corner j + 1; `node_key` maps nodes to
    their identity (coincident nodes share one), so an edge is one pair of identities,
    numbered in the order of (smaller, larger) identity (`edge_table`)."""
    t = edge_table(faces, node_key)
    return t.fac, t.loc, t.edge, t.ne


def node_identity(nodes: np.ndarray) -> np.ndarray:
    """(n,) the first node at each node's position: coincident nodes are one node (a hash
    over the coordinates, linear; -0.0 is 0.0, a node with a NaN coordinate is its own)."""
    nodes = np.ascontiguousarray(nodes, dtype=np.float64)
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise ValueError(f"node_identity: nodes of shape {nodes.shape}, expected (n, 3)")
    return _topology.node_identity(nodes)


def segment(nodes, faces, feature_angle: float = FEATURE_ANGLE_DEG, tags=None,
            flat_faces: bool = True, smooth_tags: bool = False, *, key=None,
            edges: Edges | None = None, area: np.ndarray | None = None) -> np.ndarray:
    """Patch label of each facet, (f,) int, labels 0..P-1 in order of first facet.

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f_b, k) int
        Facet blocks (corners first), indexing `nodes`; facets are numbered block after block.
    feature_angle : float
        Degrees; an edge whose two facets' normals differ by more splits them. 180 or more:
        only tags and open or non-manifold edges split.
    tags : (f,) int, optional
        Face or region tag of each facet: facets of different tags are never joined.
    flat_faces : bool
        Split flat faces from what they meet, even tangentially (a face and its fillet in a
        file without face tags: an STL): `_flat_faces`.
    smooth_tags : bool
        The tags are CAD faces (Gmsh geometrical entities), smooth inside: facets of one tag
        are joined whatever their angle (a coarse fillet's facets meet at more than the
        feature angle, yet are no feature).
    key, edges, area : optional
        The nodes' identity (`node_identity`), the facet edges (`edge_table` of `faces` by
        `key`) and the facets' area vectors (`frame.facet_area_vectors` of `nodes` and
        `faces`) where the caller has them already (`PatchedSurface`): computed otherwise.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        faces = [faces]
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    nf = sum(len(f) for f in faces)
    if nf == 0:
        return np.zeros(0, np.int64)
    if key is None:
        key = node_identity(nodes)
    if edges is None:
        edges = edge_table(faces, key)
    # manifold edges: exactly two facets (by edge, the first two half-edges' facets)
    fa, fb = _two_facets(edges)
    join = fa != fb
    if tags is not None:
        tags = np.asarray(tags).reshape(-1)
        if len(tags) != nf:
            raise ValueError(f"{len(tags)} facet tags for {nf} facets")
    # the cosine across each manifold edge of the facets' unit normals (each area vector
    # scaled by its largest component, then by its norm): the feature angle's and the flat
    # faces' test, in one compiled pass (`_edges.segment_cosines`, numpy's values bit for bit)
    cos = None
    if feature_angle < 180 or flat_faces:
        if area is None:
            area = _frame.facet_area_vectors(nodes, faces)
        cos = _edges.segment_cosines(np.ascontiguousarray(area, dtype=np.float64), fa, fb)
    if feature_angle < 180:
        smooth = cos >= np.cos(np.radians(feature_angle))
        if smooth_tags and tags is not None:
            smooth |= tags[fa] == tags[fb]
        join &= smooth
    if tags is not None:
        join &= tags[fa] == tags[fb]
    if flat_faces:
        flat = _flat_faces(nodes, faces, fa, fb, nf, key, edges, cos)
        join &= flat[fa] == flat[fb]
    # the patches: groups of facets joined, numbered in order of their first facet
    return components(nf, fa[join], fb[join])


def components(F: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(F,) int64 the connected groups of F facets joined across the pairs (a, b), numbered in
    the order of their first facet (scipy's connected_components' numbering): a compiled
    union-find, linear."""
    return _topology.components(int(F), np.ascontiguousarray(a, dtype=np.int64),
                                np.ascontiguousarray(b, dtype=np.int64))


def facet_rings(corners: np.ndarray, key: np.ndarray, label: np.ndarray, npatches: int):
    """The vertex ring of each facet (`FacetRing`: the facets sharing a node with it by
    identity `key`, itself included, sorted) and the distinct patches (`label`) of each ring,
    sorted (CSR ring_ptr, ring_patches), all int32 (ValueError where they exceed it); corners
    (F, 4), -1 past a triangle's third. One compiled pass, linear in the ring entries
    (`_topology.rings`)."""
    indptr, indices, ring_ptr, ring_patches = _topology.rings(
        np.ascontiguousarray(corners, dtype=np.int64), np.ascontiguousarray(key, dtype=np.int64),
        len(key), np.ascontiguousarray(label, dtype=np.int64), int(npatches))
    return FacetRing(indptr, indices), ring_ptr, ring_patches


def _two_facets(edges: Edges):
    """(fa, fb) the two facets of each manifold edge (of exactly two half-edges), by edge:
    those of its first and second half-edge."""
    return _edges.two_facets(_i64(edges.start), _i64(edges.order), _i64(edges.fac))


def _i64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int64)


def _flat_faces(nodes, faces, fa, fb, nf, key, edges, cos) -> np.ndarray:
    """(f,) the flat face of each facet, -1 for none: connected facets coplanar to round-off
    (normals within `tol.FLAT_COS` across their edges: `cos` of the nf facets' manifold edges
    fa, fb) forming a face with at least one node all of whose facets are in it, not on an
    open edge. Rows of coplanar facets on a curved surface (a strip between two rulings of a
    cylinder or a fillet) have no such node and stay curved. One compiled pass over the
    facets' corners (`_edges.flat_faces`), linear."""
    same = cos >= tol.FLAT_COS
    comp = components(nf, fa[same], fb[same])
    blocks = [_i64(_frame.facet_corners(f)) for f in faces]
    return _edges.flat_faces(blocks, _i64(key), len(nodes), comp, _i64(edges.start),
                             _i64(edges.ends))



#: The node order of a facet block reversed (its orientation flipped), by its node count:
#: corners reversed after the first, mid-side nodes with them, a centre kept.
_REVERSED = {3: [0, 2, 1], 4: [0, 3, 2, 1], 6: [0, 2, 1, 5, 4, 3], 7: [0, 2, 1, 5, 4, 3, 6],
             8: [0, 3, 2, 1, 7, 6, 5, 4], 9: [0, 3, 2, 1, 7, 6, 5, 4, 8]}


def consistent_winding(nodes, faces):
    """The facet blocks with every facet wound as its neighbours are (issue 22: 10% of a
    sphere's facets reversed gave wrong signs with status ok, the facets' too).

    Across every edge shared by two facets, a consistent surface runs the edge in opposite
    directions. Where some do not, each connected surface (across such edges) is oriented by
    a breadth-first walk from one facet, and its facets that disagree with the orientation
    of the larger part by area are reversed. A surface whose facets cannot all agree (a
    Möbius strip, a non-orientable join) is left as it is. Coincident nodes are one node.

    Returns (faces, reversed: the number of facets reversed, undecided: the number of facets
    on surfaces left as they are because no orientation is consistent).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    key = node_identity(np.asarray(nodes))
    fac, loc, edge, ne = facet_edges(faces, key)
    if not ne:
        return faces, 0, 0
    blocks = [_frame.facet_corners(f) for f in faces]
    corners = np.concatenate([np.pad(c, ((0, 0), (0, 4 - c.shape[1])), constant_values=-1)
                              for c in blocks])
    kind = np.concatenate([np.full(len(c), c.shape[1]) for c in blocks])
    a = key[corners[fac, loc]]
    b = key[corners[fac, np.where(loc + 1 < kind[fac], loc + 1, 0)]]
    forward = a < b
    count = np.bincount(edge, minlength=ne)
    order = np.argsort(edge, kind="stable")
    two = np.flatnonzero(count == 2)
    starts = np.searchsorted(edge[order], two)
    e1, e2 = order[starts], order[starts + 1]
    f1, f2 = fac[e1], fac[e2]
    parity = (forward[e1] == forward[e2]).astype(np.int8)  # 1: the two run it alike
    if not parity.any():
        return faces, 0, 0
    F = len(kind)
    graph = coo_matrix((np.ones(len(f1)), (f1, f2)), shape=(F, F)).tocsr()
    ncomp, comp = connected_components(graph, directed=False)
    lookup = coo_matrix((parity.astype(np.float64) + 1.0, (f1, f2)), shape=(F, F)).tocsr()
    lookup = lookup + lookup.T
    flip = np.zeros(F, np.int8)
    area = np.linalg.norm(_frame.facet_area_vectors(nodes, faces), axis=1)
    undecided = 0
    for c in np.unique(comp[np.concatenate([f1[parity == 1], f2[parity == 1]])]):
        root = int(np.flatnonzero(comp == c)[0])
        visit, pred = breadth_first_order(graph, root, directed=False, return_predecessors=True)
        for f in visit[1:]:
            p = pred[f]
            flip[f] = flip[p] ^ (int(lookup[p, f]) - 1)
        inside = comp[f1] == c
        if np.any((flip[f1[inside]] ^ flip[f2[inside]]) != parity[inside]):
            flip[visit] = 0  # no orientation agrees everywhere: left as it is
            undecided += len(visit)
            continue
        if area[visit][flip[visit] == 1].sum() > 0.5 * area[visit].sum():
            flip[visit] ^= 1  # keep the orientation of the larger part
    out, start = [], 0
    for f in faces:
        f = np.asarray(f)
        rows = flip[start:start + len(f)].astype(bool)
        if rows.any():
            f = f.copy()
            f[rows] = f[rows][:, _REVERSED[f.shape[1]]]
        out.append(f)
        start += len(f)
    return out, int(flip.sum()), undecided
