"""The guard's tables as numpy computed them before the compiled pass (`patches/_guard.pyx`):
the oracle `tests/test_guard_fast.py` checks `patches.surface`'s corner normals, edge lengths and
bends, and the guard's bounds against, bit for bit (issue 36). Copied verbatim from
`diffsurf_cli/patches/surface.py` at 0f0e242 (with `_ratio` and `_unit_rows` as changed then:
divide only where the divisor > 0)."""
from __future__ import annotations

import numpy as np

from diffsurf_cli import tol
from diffsurf_cli.mls import frame as _frame
from diffsurf_cli.patches.surface import OPEN_EDGE


def corner_normals(surf):
    """Each facet corner's normal and each facet edge's length and bend.

    A corner's normal is its smooth region's own at the node (the area-weighted normals there
    of the facets joined to each other across no sharp edge: a sharp edge is no curvature, a
    smooth edge between two tagged faces is; area weights keep slivers' unreliable normals
    from counting).

    Returns
    -------
    normal : (F, 4, 3) float   unit, zero for a triangle's fourth
    length : (F, 4) float      edge j runs from corner j to corner j + 1 (0 for none)
    bend : (F, 4) float        (n_1 - n_0) . e: its ends' normals' difference along it,
                               L κ_e for a surface of normal curvature κ_e along the edge
                               (radians for small angles), positive where the surface
                               bulges toward the normals (convex), negative where it
                               bends away (concave). Not the angle between the normals:
                               across a cylinder's slivers that is the turn of the arc
                               they span, while along their length they are straight
    """
    F = len(surf.corners)
    real = surf.corners >= 0
    corner = surf.nodes[np.maximum(surf.corners, 0)]                       # (F, 4, 3)
    nxt = _next_corner(surf.kind)
    edge = corner[np.arange(F)[:, None], nxt] - corner                     # corner j -> j + 1
    length = np.where(real, np.linalg.norm(edge, axis=2), 0.0)
    node = surf.key[np.maximum(surf.corners, 0)]
    slot = surf.smooth_region[:, None] * np.int64(len(surf.nodes)) + node     # (region, node)
    uniq, inverse = np.unique(slot[real], return_inverse=True)
    acc = np.zeros((len(uniq), 3))
    weight = np.where(real, _facet_areas(surf)[:, None], 0.0)
    np.add.at(acc, inverse.ravel(),
              (weight[..., None] * surf.facet_normal[:, None, :])[real])
    acc = _unit_rows(acc)
    normal = np.zeros((F, 4, 3))
    normal[real] = acc[inverse.ravel()]
    _crease_fans(surf, normal)
    ends = normal[np.arange(F)[:, None], nxt]
    along = _ratio(edge, length[..., None])  # a triangle's 4th edge: none (zero)
    bend = np.where(real, np.einsum("fkj,fkj->fk", ends - normal, along), 0.0)
    return normal, length, bend


def _crease_fans(surf, normal) -> None:
    """Where a crease of the CAD ends inside one smooth region (issue 34), the corners that
    `surface._crease_fans` picks take their fan's normal (the area-weighted normals of its
    facets) in `normal`, in place: the choice of corners is the surface's, the sums the
    oracle's own."""
    from diffsurf_cli.patches.surface import _crease_fans

    fans = _crease_fans(surf)
    if fans is None:
        return
    slots, fan = fans
    weight = _facet_areas(surf)[slots // 4, None] * surf.facet_normal[slots // 4]
    acc = np.zeros((int(fan.max()) + 1, 3))
    np.add.at(acc, fan, weight)
    normal.reshape(-1, 3)[slots] = _unit_rows(acc)[fan]


def _next_corner(kind: np.ndarray) -> np.ndarray:
    """(F, 4) the corner at the end of each facet edge: edge j runs from corner j to this."""
    return np.where(np.arange(4)[None] + 1 < kind[:, None], np.arange(1, 5)[None] % 4, 0)


def guard_bounds(surf):
    """The guard's bounds at each facet f (method.md, "The facets bound the smooth surface").

    Where the facets approximate a smooth surface, that surface lies within their chordal sag
    of them: an edge of length L departs from a surface of normal curvature κ_e along it by
    L² κ_e / 8 at its middle, and L κ_e is the difference of its ends' normals along it
    (`corner_normals`; over a second-order facet, its mid-side nodes give each edge's sag,
    `midside_sags`); the sag of a facet follows from its edges' (`facet_sag`). Edge by
    edge, the sag follows the bending of a sliver along its length and not across it, which
    dihedral angles alone miss (parallel slivers along a curved face meet at no angle), and
    a sliver's long diagonal across a cylinder counts the arc it spans as it projects on the
    diagonal (by cos² of the angle between them), not as the turn of the normals. An edge
    that does not resolve its surface (a fillet under one facet, its ends' normals 90° apart)
    counts its whole bend: the diffuse surface there departs from the facets as far as the
    arc does.

    A diffuse answer whose faceted foot is on f may differ from the facets' gap by no more
    than `tol.GUARD_SAG_MARGIN` times the largest sag of the facets sharing a node with f (the
    foot's neighbourhood) plus `tol.GUARD_FLOOR` node spacings (round-off), and its normal
    from f's by no more than `tol.GUARD_NORMAL_MARGIN` times the largest angle between f's
    normal and the corner normals of those of these facets that meet f below the feature
    angle (its smooth neighbourhood; in one CAD face, all), plus `tol.GUARD_NORMAL_FLOOR_DEG`,
    plus the turn of the surface between the answer's proximal point and the faceted foot:
    their distance times the largest curvature the facets around f show (an edge's bend over
    its length). A point deep inside a small hole or boss has its proximal point and its
    faceted foot a fraction of a node spacing apart, where the normals differ by more than
    the spread around one facet (linkrods o2-tags of `benchmarks/real_parts.py`: 410 of the
    412 answers the guard took without it were the nearer to the CAD; `tests/test_guard.py`,
    a second-order fillet box).
    Measured on smooth targets (spheres, tori, cylinders, a saddle, gmsh spheres of first and
    second order, `tests/test_guard.py`): the facets' own error is at most 1.5 sags, a diffuse
    answer differs from the facets by at most 1.6 sags where it is the more accurate (1.7 on
    a cylinder of 6 facets around), its normal by at most 0.7 of the angle; on a torus of 8
    facets around, where the diffuse surface is 4x further from the torus than the facets,
    by up to 6 sags.

    On the side the facets do not bend, the answer may depart by only
    `tol.GUARD_OTHER_SIDE` of their sag: facets bending toward their normal (convex) lie
    under the smooth surface they interpolate, so a diffuse surface sinking under them is no
    smoothing of them (the other way round where they bend away; both where they bend both
    ways, a saddle). The sides come from the signed edge sags of the facets of f's own patch
    sharing a node with f; where f touches an open boundary, both sides get the envelope.

    Returns
    -------
    gap_bound : (F,) float      the envelope: |g - g_f| <= gap_bound
    gap_lo, gap_hi : (F,) float the side: gap_lo <= g - g_f <= gap_hi (within the envelope)
    normal_angle : (F,) float   radians
    normal_turn : (F,) float    radians per length: the largest |bend| / length of the edges
                                of the facets sharing a node with f
    """
    F = len(surf.corners)
    real = surf.corners >= 0
    vn, length, bend = surf.corner_normal, surf.edge_length, surf.edge_bend
    edge_sag = midside_sags(surf, length * bend / 8)                   # signed
    ring = surf.ring
    rows = np.repeat(np.arange(F), np.diff(ring.indptr))

    def near(sag, same=None):  # the largest over the facets sharing a node with each facet
        out = np.zeros(F)       # (of its own patch: same)
        keep = slice(None) if same is None else same
        np.maximum.at(out, rows[keep], sag[ring.indices[keep]])
        return out

    h = surf.node_spacing[surf.corners[:, 0]]
    floor = tol.GUARD_FLOOR * h
    gap_bound = tol.GUARD_SAG_MARGIN * near(facet_sag(surf.kind, np.abs(edge_sag))) + floor
    # The side: a surface that the facets interpolate bulges past them toward their normal
    # where they bend that way (convex), lowering the gap of a point in front of them, and
    # sinks under them where they bend away (concave), raising it. From the facets of f's own
    # patch around it, whose nodes the patch's surface is fitted to (a concave fillet of the
    # next patch does not let this one sink); a crease's or an open edge's bend along itself
    # is no bend of either face (its ends' normals are a corner's).
    own = surf.label[rows] == surf.label[ring.indices]
    edge_sag = np.where(surf.edge_class >= OPEN_EDGE, 0.0, edge_sag)
    bulge = near(facet_sag(surf.kind, np.maximum(edge_sag, 0.0)), own)     # toward the normal
    hollow = near(facet_sag(surf.kind, np.maximum(-edge_sag, 0.0)), own)   # away from it
    if surf.flip:  # in the gap's own direction: the facets' normal's opposite
        bulge, hollow = hollow, bulge
    m, r = tol.GUARD_SAG_MARGIN, tol.GUARD_OTHER_SIDE
    gap_lo = -(m * bulge + r * hollow) - floor
    gap_hi = m * hollow + r * bulge + floor
    # ... but not where the foot may lie on an open boundary: past it, the facets' gap is the
    # distance to the boundary's edge, which the surface continued past it (a diffuse answer)
    # undercuts whatever its bend. There, the envelope on either side.
    edge_open = surf.edge_class == OPEN_EDGE
    open_node = np.zeros(len(surf.nodes), bool)
    for corner in (surf.corners, surf.corners[np.arange(F)[:, None], _next_corner(surf.kind)]):
        open_node[surf.key[corner[edge_open]]] = True
    at_open = (open_node[surf.key[np.maximum(surf.corners, 0)]] & real).any(axis=1)
    gap_lo = np.where(at_open, -gap_bound, gap_lo)
    gap_hi = np.where(at_open, gap_bound, gap_hi)
    # the spread of the normals around f: f's normal against the corner normals of its
    # smooth neighbours (those meeting it below the feature angle; in one CAD face, any)
    cf = np.clip(np.einsum("ij,ij->i", surf.facet_normal[rows],
                           surf.facet_normal[ring.indices]), -1, 1)
    limit = 180.0 if surf.feature_angle is None else min(surf.feature_angle, 180.0)
    smooth = cf >= np.cos(np.radians(limit))
    if surf.smooth_tags:
        smooth |= surf.tags[rows] == surf.tags[ring.indices]
    elif surf.coarse_bend is not None and limit < 180:  # one region of a coarse curve: any
        region = surf.smooth_region
        curved = np.zeros(region.max() + 1, bool)
        curved[region[surf.edge_facets[surf.coarse_bend, 0]]] = True
        smooth |= (region[rows] == region[ring.indices]) & curved[region[rows]]
    spread = np.zeros(F)
    for i in range(4):
        ok = smooth & real[ring.indices, i]
        c = np.clip(np.einsum("ij,ij->i", surf.facet_normal[rows[ok]],
                              vn[ring.indices[ok], i]), -1, 1)
        np.maximum.at(spread, rows[ok], np.arccos(c))
    normal_angle = tol.GUARD_NORMAL_MARGIN * spread + np.radians(tol.GUARD_NORMAL_FLOOR_DEG)
    per_edge = _ratio(np.abs(bend), length)
    normal_turn = near(per_edge.max(axis=1))
    return gap_bound, gap_lo, gap_hi, normal_angle, normal_turn


def midside_sags(surf, estimate: np.ndarray) -> np.ndarray:
    """(F, 4) each facet edge's signed sag, positive where the surface bulges toward the
    facet's normal: over a second-order facet, its mid-side node's distance from the edge's
    middle (the cell's own curve departs from the edge by that much there), signed by its
    side of the facet; else `estimate` (from the corner normals, signed)."""
    sags, start = estimate.copy(), 0
    for f in surf.faces:
        k = _frame.CORNERS[f.shape[1]]
        if f.shape[1] >= 2 * k:                         # triangle6/7, quad8/9
            rows = slice(start, start + len(f))
            ends = f[:, (np.arange(k) + 1) % k]
            middle = 0.5 * (surf.nodes[f[:, :k]] + surf.nodes[ends])
            off = surf.nodes[f[:, k:2 * k]] - middle
            side = np.einsum("fkj,fj->fk", off, surf.facet_normal[rows])
            sags[rows, :k] = np.linalg.norm(off, axis=2) * np.where(side < 0, -1.0, 1.0)
        start += len(f)
    return sags


def facet_sag(kind: np.ndarray, edge_sag: np.ndarray) -> np.ndarray:
    """(F,) the largest departure of a surface from the facets interpolating it, from the sags
    of their edges (F, 4): edge j, corner j to j + 1, departs by s_j at its middle.

    Over a triangle, a quadratic surface departs from the plane of its corners by
    4 Σ_{i<j} λ_i λ_j s_ij at barycentric coordinates λ; its largest value on the triangle is
    4 s_a s_b s_c / (2 (s_a s_b + s_b s_c + s_c s_a) - s_a² - s_b² - s_c²) when the three sags
    obey the triangle inequality (a sphere: 4/3 of an edge's), else the largest edge's (a
    cylinder: the edge across the axis). Over a quad, the bilinear facet departs by the sum
    of the two directions' sags at its middle (a paraboloid; a cylinder: one direction's).
    """
    a, c, b = edge_sag[:, 0], edge_sag[:, 1], edge_sag[:, 2]       # corners 01, 12, 20
    edges = np.maximum(np.maximum(a, b), c)
    inside = (a + b > c) & (b + c > a) & (c + a > b)
    d = 2 * (a * b + b * c + c * a) - a * a - b * b - c * c
    middle = np.where(inside & (d > 0), 4 * a * b * c / np.where(d > 0, d, 1.0), 0.0)
    triangle = np.maximum(edges, middle)
    quad = (np.maximum(edge_sag[:, 0], edge_sag[:, 2])
            + np.maximum(edge_sag[:, 1], edge_sag[:, 3]))
    return np.where(kind == 4, quad, triangle)


def support_floor(surf) -> np.ndarray:
    """(F,) the least local spacing of a facet's patch over it (issue 19, item 2): over a
    quad, `tol.SUPPORT_FACET_FRACTION` of its longest edge (its nearest nodes are across it:
    their support is one row, whose reduced basis cannot see the bending along the quad, and
    whose hull leaves the points between rows off the target), of its longest edge's half
    over a second-order quad (a node every half edge); 0 over a triangle."""
    half = np.concatenate([np.full(len(f), f.shape[1] > 4) for f in surf.faces])
    longest = surf.edge_length.max(axis=1)
    return np.where(surf.kind == 4, tol.SUPPORT_FACET_FRACTION * longest
                    / np.where(half, 2.0, 1.0), 0.0)


def _facet_areas(surf) -> np.ndarray:
    """(F,) area of each facet (a quad's, as two triangles)."""
    corner = surf.nodes[np.maximum(surf.corners, 0)]
    a = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    quad = surf.kind == 4
    b = np.cross(corner[:, 2] - corner[:, 0], corner[:, 3] - corner[:, 0])
    return 0.5 * np.linalg.norm(a + np.where(quad[:, None], b, 0.0), axis=1)


def _ratio(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a / b where b > 0, else 0 (broadcast): scale-free, where a floor on b (1e-300) would
    overflow a / b for a target 1e9 in size wherever b is 0 and a is not."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return np.divide(a, b, out=np.zeros(a.shape), where=b > 0)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    """Rows of v scaled to unit length; zero rows (a degenerate facet) stay zero."""
    return _ratio(v, np.linalg.norm(v, axis=-1, keepdims=True))
