"""Parts with features (issue 11): gmsh OpenCASCADE scenes with their exact signed distance
(> 0 outside, the gap convention) and a region per contactor, for tests/test_patches.py and
benchmarks/feature_targets.py. Needs gmsh (`gmsh_scenes`).

Contactors are drawn uniformly in the part's box grown by the band, kept where the exact
|distance| is within the band (2% of the part size by default: the issue's "no point within
2% of the part size left outside"): inside and outside, over faces and in the wedges beyond
edges. The region of a contactor is that of its exact closest point:
'flat' a flat face farther than two elements from a sharp edge, 'edge' within two elements
of one (or closest to it), 'fillet' a fillet (rolling-ball blend), 'curved' a curved face
farther than two elements from a sharp edge. Scenes: a box, a box with filleted edges, a
capped cylinder, a plate meshed fine on top and coarse below, a lens (two spherical caps
meeting at a sharp circular edge).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import gmsh_scenes


def _box_sdf(p, lo, hi):
    c, e = 0.5 * (lo + hi), 0.5 * (hi - lo)
    q = np.abs(p - c) - e
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def _box_edge_distance(p, lo, hi):
    """Distance of the box's closest point to p to the nearest edge of the box."""
    c, e = 0.5 * (lo + hi), 0.5 * (hi - lo)
    q = np.abs(p - c) - e  # per axis, <= 0 inside the slab
    foot = np.clip(np.abs(p - c), 0, e)  # |foot - c| per axis (outside points)
    inside = (q <= 0).all(axis=1)
    # inside: the foot is on the nearest face (axis of max q); its distance to that face's
    # edges is the min over the other two axes of e - |p - c|
    k = np.argmax(q, axis=1)
    gaps = e - np.abs(p - c)
    gaps_in = np.where(np.arange(3)[None, :] == k[:, None], np.inf, gaps)
    d_in = gaps_in.min(axis=1)
    # outside: the foot is clamped on the axes where q > 0; on 2+ such axes it is on an edge
    out_axes = (q > 0).sum(axis=1)
    free = np.where(q > 0, np.inf, e - foot)
    d_out = np.where(out_axes >= 2, 0.0, free.min(axis=1))
    return np.where(inside, d_in, d_out)


@dataclass
class Scene:
    name: str
    path: str
    size: float          # part size (largest dimension)
    h: float             # element size (edge bands are two of these)
    sdf: callable        # (m, 3) -> (m,) exact signed distance, > 0 outside
    region: callable     # (m, 3) -> (m,) region names
    box: tuple

    def sample(self, n, band=0.02, seed=0):
        """n contactors within band x size of the surface (module doc)."""
        rng = np.random.default_rng(seed)
        lo, hi = self.box
        w = band * self.size
        out = []
        got = 0
        while got < n:
            p = rng.uniform(lo - w, hi + w, size=(20 * n, 3))
            p = p[np.abs(self.sdf(p)) <= w]
            out.append(p)
            got += len(p)
        return np.concatenate(out)[:n]


def box(tmp, size=0.2):
    lo, hi = np.zeros(3), np.array([2.0, 1.0, 1.0])
    path = gmsh_scenes.box(tmp / "box.msh", *hi, size=size)
    return Scene("box", path, 2.0, size, lambda p: _box_sdf(p, lo, hi),
                 lambda p: np.where(_box_edge_distance(p, lo, hi) <= 2 * size, "edge", "flat"),
                 (lo, hi))


def thin_plate(tmp, top=0.4, bottom=2.5):
    lo, hi = np.zeros(3), np.array([10.0, 10.0, 2.0])
    path = gmsh_scenes.thin_plate(tmp / "plate.msh", *hi, top=top, bottom=bottom)

    def region(p):
        # two elements of the face's own size (coarse below)
        foot_z = np.clip(p[:, 2], 0, 2)
        h = np.where(foot_z < 1.0, bottom, top)
        return np.where(_box_edge_distance(p, lo, hi) <= 2 * h, "edge", "flat")
    return Scene("thin plate", path, 10.0, top, lambda p: _box_sdf(p, lo, hi), region,
                 (lo, hi))


def capped_cylinder(tmp, size=0.08, radius=0.5, height=1.0):
    path = gmsh_scenes.capped_cylinder(tmp / "cylinder.msh", radius, height, size)

    def parts(p):
        r = np.hypot(p[:, 0], p[:, 1])
        dr = r - radius
        dz = np.abs(p[:, 2] - height / 2) - height / 2
        return r, dr, dz

    def sdf(p):
        _, dr, dz = parts(p)
        return np.hypot(np.maximum(dr, 0), np.maximum(dz, 0)) + np.minimum(np.maximum(dr, dz), 0)

    def region(p):
        _, dr, dz = parts(p)
        inside = (dr <= 0) & (dz <= 0)
        on_side = np.where(inside, dr > dz, (dr > 0) & (dz <= 0))
        on_cap = np.where(inside, dr >= dz, (dr <= 0) & (dz > 0))
        # distance of the closest point to the rim: axial on the side, radial on a cap
        to_rim = np.where(on_side, -dz, np.where(on_cap, -dr, 0.0))
        near = to_rim <= 2 * size
        return np.where(near, "edge", np.where(on_side, "curved", "flat"))
    return Scene("capped cylinder", path, 1.0, size, sdf, region,
                 (np.array([-radius, -radius, 0.0]), np.array([radius, radius, height])))


def fillet_box(tmp, size=0.07, fillet=0.25):
    lo, hi = np.zeros(3), np.array([2.0, 1.0, 1.0])
    path = gmsh_scenes.fillet_box(tmp / "fillet_box.msh", *hi, fillet=fillet, size=size)
    inner_lo, inner_hi = lo + fillet, hi - fillet

    def sdf(p):
        return _box_sdf(p, inner_lo, inner_hi) - fillet

    def region(p):
        # closest point of the inner box: on a face (flat), else on an edge or corner (fillet)
        c, e = 0.5 * (inner_lo + inner_hi), 0.5 * (inner_hi - inner_lo)
        q = np.abs(p - c) - e
        outside_axes = (q > 0).sum(axis=1)
        inside = outside_axes == 0
        return np.where(inside | (outside_axes == 1), "flat", "fillet")
    return Scene("fillet box", path, 2.0, size, sdf, region, (lo, hi))


def lens(tmp, size=0.1, radius=1.0, offset=1.2):
    path = gmsh_scenes.lens(tmp / "lens.msh", radius, offset, size)
    c1, c2 = np.array([0, 0, -offset / 2]), np.array([0, 0, offset / 2])
    rim = np.sqrt(radius ** 2 - (offset / 2) ** 2)  # the edge: a circle of this radius at z = 0

    def parts(p):
        d1, d2 = np.linalg.norm(p - c1, axis=1), np.linalg.norm(p - c2, axis=1)
        # the projection onto each sphere, and whether it lies on its cap (inside the other ball)
        f1 = c1 + radius * (p - c1) / d1[:, None]
        f2 = c2 + radius * (p - c2) / d2[:, None]
        on1 = np.linalg.norm(f1 - c2, axis=1) <= radius
        on2 = np.linalg.norm(f2 - c1, axis=1) <= radius
        r = np.hypot(p[:, 0], p[:, 1])
        to_rim = np.hypot(r - rim, p[:, 2])
        return d1, d2, on1, on2, to_rim

    def sdf(p):
        d1, d2, on1, on2, to_rim = parts(p)
        inside = (d1 <= radius) & (d2 <= radius)
        out = np.minimum.reduce([np.where(on1, np.abs(d1 - radius), np.inf),
                                 np.where(on2, np.abs(d2 - radius), np.inf), to_rim])
        return np.where(inside, -np.minimum(radius - d1, radius - d2), out)

    def region(p):
        d1, d2, on1, on2, to_rim = parts(p)
        inside = (d1 <= radius) & (d2 <= radius)
        # the closest point: on a cap (its projection) or the rim; its distance to the rim
        cap = np.where(inside, np.where(radius - d1 < radius - d2, 1, 2),
                       np.where(on1 & (np.abs(d1 - radius) <= to_rim), 1,
                                np.where(on2 & (np.abs(d2 - radius) <= to_rim), 2, 0)))
        q = np.where(cap[:, None] == 1, c1 + radius * (p - c1) / d1[:, None],
                     c2 + radius * (p - c2) / d2[:, None])
        q_to_rim = np.hypot(np.hypot(q[:, 0], q[:, 1]) - rim, q[:, 2])
        near = (cap == 0) | (q_to_rim <= 2 * size)
        return np.where(near, "edge", "curved")
    return Scene("lens", path, 2 * rim, size, sdf, region,
                 (np.array([-rim, -rim, -(radius - offset / 2)]),
                  np.array([rim, rim, radius - offset / 2])))


SCENES = {"box": box, "fillet_box": fillet_box, "capped_cylinder": capped_cylinder,
          "thin_plate": thin_plate, "lens": lens}


def errors(scene, points, surf, facets):
    """Per region: (count, diffsurf RMS, max, facets RMS, max, % outside), and the raw arrays
    (exact, diffuse gap, facet gap, answered mask, regions)."""
    exact = scene.sdf(points)
    d, f = surf.project(points), facets.project(points)
    regions = scene.region(points)
    answered = np.isin(d.status, (0, 1, 2))
    table = {}
    for name in ("flat", "edge", "fillet", "curved", "all"):
        sel = regions == name if name != "all" else np.ones(len(points), bool)
        if not sel.any():
            continue
        ok = sel & answered
        ed = np.abs(d.gap[ok] - exact[ok])
        ef = np.abs(f.gap[sel] - exact[sel])
        table[name] = (int(sel.sum()), _rms(ed), ed.max(initial=0.0), _rms(ef),
                       ef.max(initial=0.0), 100.0 * (sel & ~answered).sum() / sel.sum())
    return table, (exact, d, f, answered, regions)


def _rms(e):
    return float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan")
