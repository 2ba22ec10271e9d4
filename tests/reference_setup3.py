"""The numpy that `diffsurf_cli.patches._edges` replaced (issue 36), verbatim as the package had
it just before: the segmentation's unit normals and edge cosines (`segment.segment`), its flat
faces (`segment._flat_faces`, `_open_nodes`) and `PatchedSurface._classify_edges` (as a function
of a surface's attributes). Each returns what the package computed then."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from diffsurf_cli import tol
from diffsurf_cli.mls import frame as _frame
from diffsurf_cli.patches import segment as _segment
from diffsurf_cli.patches.surface import INSIDE, OPEN_EDGE, SHARP, SMOOTH, _int32


def two_facets(edges):
    at = edges.start[:-1][np.diff(edges.start) == 2]
    return edges.fac[edges.order[at]], edges.fac[edges.order[at + 1]]


def segment_unit(area):
    """The segmentation's unit normals of the facets' area vectors."""
    area = np.asarray(area, dtype=np.float64)
    top = np.maximum(np.maximum(np.abs(area[:, 0]), np.abs(area[:, 1])),
                     np.abs(area[:, 2]))[:, None]
    unit = np.divide(area, top, out=np.zeros_like(area), where=top > 0)
    norm = _frame.row_norms(unit)[:, None]
    return np.divide(unit, norm, out=np.zeros_like(unit), where=norm > 0)


def segment_cosines(area, fa, fb):
    unit = segment_unit(area)
    return np.einsum("ij,ij->i", unit[fa], unit[fb])


def flat_faces(nodes, faces, fa, fb, unit, key, edges, cos=None):
    nf = len(unit)
    if cos is None:
        cos = np.einsum("ij,ij->i", unit[fa], unit[fb])
    same = cos >= tol.FLAT_COS
    comp = _segment.components(nf, fa[same], fb[same])
    fnode, fcomp = [], []
    start = 0
    for f in faces:
        c = _frame.facet_corners(f)
        fnode.append(c.ravel())
        fcomp.append(np.repeat(comp[start:start + len(c)], c.shape[1]))
        start += len(c)
    fnode = key[np.concatenate(fnode)]
    fcomp = np.concatenate(fcomp)
    n = len(nodes)
    some = np.full(n, -1)
    some[fnode] = fcomp
    mixed = np.zeros(n, bool)
    mixed[fnode[fcomp != some[fnode]]] = True
    inner = (some >= 0) & ~mixed & ~_open_nodes(edges, n)
    has_inner = np.zeros(nf, bool)
    has_inner[some[inner]] = True
    sizes = np.bincount(comp, minlength=nf)
    return np.where(has_inner[comp] & (sizes[comp] > 1), comp, -1)


def _open_nodes(edges, n):
    out = np.zeros(n, bool)
    out[edges.ends[np.diff(edges.start) == 1].ravel()] = True
    return out


def classify_edges(surf, edges):
    """`PatchedSurface._classify_edges` on `surf` (its key, label, corners, nodes,
    facet_normal, feature_angle, smooth_tags, tags) and its facet edges: a namespace of
    edge_class, vertex_class, edge_facets, edge_sharp, smooth_region."""
    out = SimpleNamespace()
    fac, loc, edge, ne = edges.fac, edges.loc, edges.edge, edges.ne
    two = np.diff(edges.start) == 2
    at = edges.start[:-1][two]
    f1, f2 = fac[edges.order[at]], fac[edges.order[at + 1]]
    flo, fhi = np.minimum(f1, f2), np.maximum(f1, f2)
    cos = np.ones(ne)
    cos[two] = np.einsum("ij,ij->i", surf.facet_normal[flo], surf.facet_normal[fhi])
    angle = 180.0 if surf.feature_angle is None else min(surf.feature_angle, 180.0)
    sharp = cos < np.cos(np.radians(angle))
    if surf.smooth_tags:
        same_tag = np.zeros(ne, bool)
        same_tag[two] = surf.tags[flo] == surf.tags[fhi]
        sharp &= ~same_tag
    inside = np.zeros(ne, bool)
    inside[two] = surf.label[flo] == surf.label[fhi]
    cls = np.where(~two, OPEN_EDGE, np.where(sharp, SHARP, np.where(inside, INSIDE,
                                                                     SMOOTH)))
    cls = cls.astype(np.int8)
    out.edge_class = np.zeros((len(surf.corners), 4), np.int8)
    out.edge_class[fac, loc] = cls[edge]
    vertex_class = np.zeros(len(surf.nodes), np.int8)
    for c in np.unique(cls):
        vertex_class[edges.ends[cls == c].ravel()] = c
    out.vertex_class = vertex_class[surf.key]
    out.edge_facets = _int32(np.stack([flo, fhi], axis=1))
    out.edge_sharp = sharp[two]
    smooth = ~out.edge_sharp
    out.smooth_region = _segment.components(len(surf.corners), flo[smooth], fhi[smooth])
    return out
