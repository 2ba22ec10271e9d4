"""Measure the speed/accuracy trade of engine settings on the user's own target.

Accuracy without an exact answer, by leave-one-out: the nodes of a finite-element target lie
on the true surface, so a node held out of the fit is a point whose exact gap is zero. Build
the diffuse surface without it (the node, and the facets that use it, removed) and project it:
its |gap| is an error estimate at a point where the surface was not told the answer.

To stay cheap, nodes are held out in batches: every node of a batch is farther than two
support radii from the others, so one surface built without the whole batch answers for each
of them as if it alone had been removed. A few batches, a few hundred nodes in all (seeded),
give the RMS and the largest error, absolute and in units of the local node spacing h.

The estimate is pessimistic in absolute terms: removing a node coarsens the mesh locally (the
hole is about 2h wide where the mesh is h), and the diffuse error grows as a power of the
spacing (O(h^4) for the quadratic basis on smooth targets, `benchmarks/accuracy.py`), so the
held-out error is several times the error at the same place with the node present. It ranks
settings; it is not the error of the full mesh. Boundary nodes of an open target are never
held out: without them the surface there would be an extrapolation, which no setting can fix.

Speed: each setting projects the user's points, or points sampled near the target (random
points on the facets, offset along the facet normal by up to one local spacing), and the
throughput is the best of a few repeats (points/s; surface construction excluded). Fewer
points than `TIMING_POINTS` are repeated up to that many for the timing: a few hundred points
take about a millisecond, the size of the per-call overheads.

`recommend` picks the fastest setting whose estimated RMS error is within `TOLERANCE` of the
best one, among those that leave no more points outside or failed than the others do; speeds
within `SPEED_TIE` of the fastest count as a tie, which the smaller error wins.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from . import tol
from .mls import surface as _surface
from .mls.basis import size as basis_size
from .mls.frame import facet_corners, linear_facets
from .mls.surface import DEFAULT_RADIUS, KNN_RADIUS_FACTOR, DiffuseSurface
from .nodes import node_spacing as _node_spacing
from .patches.segment import FEATURE_ANGLE_DEG
from .projection import OUTSIDE

#: A setting is "as accurate" as the best one when its estimated RMS error is within this
#: factor of the best (the leave-one-out estimate scatters by about this much between seeds).
TOLERANCE = 1.25
#: Throughputs within this factor of each other are a tie (the jitter between runs on a
#: loaded machine), broken by the smaller estimated error.
SPEED_TIE = 1.1
#: Held-out nodes are farther apart than this many support radii (their supports are disjoint).
SEPARATION = 2.0
#: Points sampled near the target for the timing when the user gives none.
TIMING_POINTS = 10_000
#: Timing: best of at least this many repeats, and more while under `MIN_TIME` seconds in all
#: (a few hundred points take milliseconds: one run would time the overheads); no more once
#: `BUDGET` seconds are spent.
REPEAT = 5
MIN_TIME = 0.5
BUDGET = 5.0
#: A warm-up call on this many points precedes the timing (a compiled kernel compiles on its
#: first call; that is not throughput).
WARMUP = 64
#: A held-out node sits in the hole its removal made, about one edge length from the nearest
#: remaining node; `surface.OUTSIDE_SPACINGS` (1 spacing) would call a fifth of them 'outside'
#: (measured on icospheres: the nodes of the coarsest neighbourhoods, the ones whose error
#: matters most). The surfaces built without held-out nodes use this limit instead
#: (DiffuseSurface's `outside_spacings`), so they are all measured; the hull test that finds
#: open edges is unchanged.
HOLE_SPACINGS = 2.0


@dataclass
class Estimate:
    """Accuracy and speed of one setting on one target.

    name : str                the setting's name (a preset)
    options : dict            its engine options (keyword arguments of DiffuseSurface)
    frame : str               the frame it resolved to ('global' or 'local')
    loo_rms, loo_max : float  RMS and largest |gap| of the held-out nodes (target units)
    loo_rms_h, loo_max_h : float   the same in units of each node's local spacing
    loo_bad : int             held-out nodes left outside or failed (not in the RMS)
    rate : float              points/s projecting `points` (best of the repeats)
    points : int              number of timed points
    bad : int                 timed points outside or failed
    loo_error : (s,) float    |gap| of each held-out node (NaN where outside or failed)
    """

    name: str
    options: dict
    frame: str
    loo_rms: float
    loo_max: float
    loo_rms_h: float
    loo_max_h: float
    loo_bad: int
    rate: float
    points: int
    bad: int
    loo_error: np.ndarray = field(repr=False)


@dataclass
class Tuning:
    """What `tune` measured.

    estimates : list of Estimate   one per setting, in the order given
    recommended : str or None      the name `recommend` picked (None: no setting has an error
                                   estimate among those with the fewest failures)
    held_out : (s,) int            indices of the held-out nodes, in batch order
    batches : list of (b,) int     the batches (indices into the nodes)
    spacing : (s,) float           local node spacing h at each held-out node
    sampled : bool                 True when the timed points were sampled near the target
    """

    estimates: list
    recommended: str
    held_out: np.ndarray
    batches: list
    spacing: np.ndarray
    sampled: bool


def support_radius(options: dict) -> float:
    """Support radius of a setting in node spacings (an upper estimate for 'knn').

    For k nearest nodes on a mesh of spacing h the farthest is about h sqrt(k/π) away on a
    quad mesh (fewer on a triangle mesh, which is denser), and R is `KNN_RADIUS_FACTOR` times it.
    """
    if options.get("method") == "quadric":
        return float(options.get("radius") or 2.0)
    if options.get("support", "radius") == "knn":
        k = options.get("k") or 3 * basis_size(options.get("basis", "quadratic"))
        return KNN_RADIUS_FACTOR * float(np.sqrt(k / np.pi))
    radius = options.get("radius")
    if radius is None:
        radius = DEFAULT_RADIUS[options.get("basis", "quadratic")]
    return float(radius)


def node_spacing(nodes: np.ndarray) -> np.ndarray:
    """Local node spacing h at each node, (n,): DiffuseSurface's own measure
    (`facet.surface.node_spacing`, exact duplicates merged)."""
    return _node_spacing(np.asarray(nodes, dtype=np.float64))


def boundary_nodes(n: int, faces: list) -> np.ndarray:
    """Boolean mask (n,) of the nodes on an open boundary (edges used by one facet only).

    Nodes in no facet (such as mid-side nodes of higher-order cells) are also marked, so that
    only facet corners are held out.
    """
    edges, used = [], np.zeros(n, dtype=bool)
    for f in faces:
        f = np.asarray(f, dtype=np.int64)
        if not len(f):
            continue
        used[f.ravel()] = True
        edges.append(np.sort(np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2), axis=1))
    mask = ~used
    if edges:
        e, count = np.unique(np.concatenate(edges), axis=0, return_counts=True)
        mask[e[count == 1].ravel()] = True
    return mask


def holdout_batches(nodes: np.ndarray, faces: list, spacing: np.ndarray, separation: float,
                    sample: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Batches of interior nodes to hold out, pairwise farther than `separation` spacings.

    Greedy over a seeded random order of the interior nodes: a node joins the batch unless it
    lies within `separation` x h of a node already in it (h the local spacing of that node);
    nodes left out start the next batch. Stops at `sample` nodes in all, or when every interior
    node has been held out once. A target without interior nodes (a strip one element wide,
    whose nodes are all on its open edges) holds out the nodes of two facets or more (not its
    ends).
    """
    candidates = np.flatnonzero(~boundary_nodes(len(nodes), faces))
    if not len(candidates):
        used = np.zeros(len(nodes), dtype=np.int64)
        for f in faces:
            f = np.asarray(f, dtype=np.int64)
            if len(f):
                np.add.at(used, f.ravel(), 1)
        candidates = np.flatnonzero(used >= 2)
    order = list(rng.permutation(candidates))
    tree = cKDTree(nodes)
    batches, total = [], 0
    while order and total < sample:
        blocked = np.zeros(len(nodes), dtype=bool)
        batch = []
        for i in order:
            if blocked[i]:
                continue
            batch.append(i)
            total += 1
            if total >= sample:
                break
            blocked[tree.query_ball_point(nodes[i], separation * spacing[i])] = True
        taken = set(batch)
        order = [i for i in order if i not in taken]
        batches.append(np.array(batch, dtype=np.int64))
    return batches


def without(nodes: np.ndarray, faces: list, drop: np.ndarray, tags=None):
    """The target without the nodes `drop` and the facets that use them, reindexed.

    Returns
    -------
    nodes : (n - len(drop), 3) float
    faces : list of (f', 3) or (f', 4) int
        Higher-order facets come back as their linear sub-facets (`frame.linear_facets`).
    tags : (f',) int or None
        The face tags (one per facet of `faces`, blocks one after the other) of the facets
        kept, where `tags` are given.
    """
    keep = np.ones(len(nodes), dtype=bool)
    keep[drop] = False
    new = np.cumsum(keep) - 1
    out, out_tags = [], []
    blocks = [np.asarray(f, dtype=np.int64) for f in faces]
    starts = np.cumsum([0] + [len(f) for f in blocks])
    # a held-out corner takes only the sub-facets around it: the mid-side nodes of its cells
    # keep a normal (else the sheet test drops them too and the hole is a cell wide)
    for b, block in enumerate(blocks):
        for f in linear_facets([block]):
            ok = keep[f].all(axis=1) if len(f) else np.zeros(0, bool)
            out.append(new[f[ok]] if len(f) else f)
            if tags is not None:
                out_tags.append(np.asarray(tags)[starts[b]:starts[b + 1]][ok])
    return nodes[keep], out, (np.concatenate(out_tags) if tags is not None else None)


def leave_one_out(nodes: np.ndarray, faces: list, options: dict, batches: list, *,
                  frame: str | None = None, flip: bool = False, patches: dict | None = None,
                  full_normals: np.ndarray | None = None):
    """Signed gap of each held-out node to the diffuse surface built without its batch.

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f, 3) or (f, 4) int
    options : dict   engine options (keyword arguments of DiffuseSurface)
    batches : list of (b,) int
    frame : str, optional   the frame resolved on the full target (so 'auto' decides once;
                            one diffuse surface)
    flip : bool
    patches : dict, optional
        The patched surface's settings (`feature_angle`, `tags`, `smooth_tags`): the
        surfaces are then `PatchedSurface`s of the target without the batch, as `project`
        builds them, the guard off (the held-out node's distance to the diffuse surface is
        the measure, not the facets' answer over the hole).
    full_normals : (n, 3) float, optional
        The quadric method's nodal normals on the whole target: the surfaces without a batch
        keep them at the nodes that remain.

    Returns
    -------
    gap : (s,) float    NaN where the held-out node is outside or failed
    status : (s,) int8  status codes (projection.STATUS)
    """
    gaps, statuses = [], []
    outside = max(HOLE_SPACINGS, _surface.OUTSIDE_SPACINGS)
    for batch in batches:
        tags = None if patches is None else patches.get("tags")
        sub_nodes, sub_faces, sub_tags = without(nodes, faces, batch, tags)
        if options.get("method") == "quadric":
            surface = _quadric(sub_nodes, sub_faces, options, flip)
            # the remaining nodes keep the normals the whole target gives them: their facets
            # into the hole are removed with it, and normals from the rest alone would tilt
            # toward one side, an error of the hole (measured: 2x the held-out |gap| on a
            # 24x8 torus), not of the fit at a node that is there
            if full_normals is not None:
                keep = np.ones(len(nodes), dtype=bool)
                keep[batch] = False
                surface.normals = full_normals[keep]
        elif patches is None:
            surface = DiffuseSurface(sub_nodes, sub_faces, flip=flip,
                                     **{**options, "frame": frame}, outside_spacings=outside)
        else:
            surface = _patched(sub_nodes, sub_faces, options, flip,
                               dict(patches, tags=sub_tags), guard=False,
                               outside_spacings=outside)
        result = surface.project(nodes[batch])
        gaps.append(result.gap)
        statuses.append(result.status)
    return np.concatenate(gaps), np.concatenate(statuses)


def _quadric(nodes, faces, options, flip):
    """The quadric method's surface (`QuadricSurface`; no patches, no guard, whatever the
    patched surface's settings)."""
    from .mls.quadric import QuadricSurface

    return QuadricSurface(nodes, faces, flip=flip, check_winding=False,
                          **{k: v for k, v in options.items() if k in ("radius", "beta")})


def _patched(nodes, faces, options, flip, patches, guard=True, **extra):
    """The surface `project` builds: a PatchedSurface (module `patches.surface`)."""
    from .patches.surface import PatchedSurface

    angle = patches.get("feature_angle", FEATURE_ANGLE_DEG)
    return PatchedSurface(nodes, faces, feature_angle=None if angle is None or angle >= 180
                          else angle, tags=patches.get("tags"),
                          smooth_tags=patches.get("smooth_tags", False), flip=flip,
                          guard=guard, **options, **extra)


def sample_near_facets(nodes: np.ndarray, faces: list, m: int, rng: np.random.Generator,
                       spacing: np.ndarray | None = None) -> np.ndarray:
    """Random points near the target: uniform on the facets (by area), offset along the facet
    normal by a uniform amount in [-h, h], h the mean local spacing of the facet's corners.

    Quads are split into two triangles. Returns (m, 3) float.
    """
    if spacing is None:
        spacing = node_spacing(nodes)
    tris = []
    for f in faces:
        f = np.asarray(f, dtype=np.int64)
        if not len(f):
            continue
        tris.append(f if f.shape[1] == 3 else np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]]))
    if not tris:
        raise ValueError("the target has no facets to sample points near")
    tri = np.concatenate(tris)
    a, b, c = nodes[tri[:, 0]], nodes[tri[:, 1]], nodes[tri[:, 2]]
    cross = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    if not area.sum() > 0:
        raise ValueError("the target's facets have no area")
    pick = rng.choice(len(tri), size=m, p=area / area.sum())
    u, v = rng.random((2, m))
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    base = a[pick] + u[:, None] * (b - a)[pick] + v[:, None] * (c - a)[pick]
    normal = cross[pick] / np.maximum(2 * area[pick], tol.TINY)[:, None]
    h = spacing[tri[pick]].mean(axis=1)
    return base + (rng.uniform(-1, 1, m) * h)[:, None] * normal


def throughput(surface, points: np.ndarray, repeat: int = REPEAT, budget: float = BUDGET,
               min_time: float = MIN_TIME):
    """Points per CPU second of ``surface.project(points)``, best run of several (after a
    warm-up).

    CPU time (of every thread of the process), not wall time: another job on the machine then
    does not change the figure, nor the recommendation. At least `repeat` runs, more while the
    runs add up to less than `min_time` CPU seconds, none started once `budget` seconds are
    spent. Returns (rate, the last Projection).
    """
    surface.project(points[:WARMUP])
    best, spent, runs, result = np.inf, 0.0, 0, None
    while runs == 0 or (spent < budget and (runs < repeat or spent < min_time)):
        start = time.process_time()
        result = surface.project(points)
        elapsed = time.process_time() - start
        best, spent, runs = min(best, elapsed), spent + elapsed, runs + 1
    return len(points) / max(best, 1e-12), result


def recommend(estimates: list, tolerance: float = TOLERANCE, tie: float = SPEED_TIE):
    """The fastest setting whose LOO RMS error is within `tolerance` x the best one, among the
    settings with the fewest failures; None when no setting has a finite error.

    Failures are the held-out nodes plus the timed points a setting leaves outside or failed:
    only the settings with the fewest compete, whatever their speed (a setting must never buy
    speed by giving up points, and none with more failures than another is recommended).
    Among those within `tolerance` of the best error, throughputs within `tie` x the fastest
    are a tie, won by the smaller error.
    """
    fair = [e for e in estimates if np.isfinite(e.loo_rms)]
    if not fair:
        return None
    fewest = min(e.loo_bad + e.bad for e in estimates)
    fair = [e for e in fair if e.loo_bad + e.bad <= fewest]
    if not fair:  # the settings with the fewest failures have no error estimate
        return None
    best = min(e.loo_rms for e in fair)
    close = [e for e in fair if e.loo_rms <= tolerance * best]
    fastest = max(e.rate for e in close)
    return min((e for e in close if e.rate * tie >= fastest), key=lambda e: e.loo_rms).name


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def tune(nodes, faces, settings: dict, points=None, *, sample: int = 200, seed: int = 0,
         flip: bool = False, timing_points: int = TIMING_POINTS, repeat: int = REPEAT,
         budget: float = BUDGET, min_time: float = MIN_TIME, progress=None,
         patches: dict | None = None) -> Tuning:
    """Estimate accuracy (leave-one-out) and throughput of each setting on a target.

    Parameters
    ----------
    nodes : (n, 3) float
        Target nodes.
    faces : list of (f, 3) or (f, 4) int
        Facet corners (orientation, boundary detection, held-out facets, sampled points);
        blocks of higher-order facets (`frame.cell_faces`) give mid-side nodes their cells'
        normals in every surface built, the corners alone the rest.
    settings : dict of str -> dict
        Named engine options (e.g. the CLI presets), each the keyword arguments of
        DiffuseSurface; or the quadric method's (`presets.QUADRIC`: method 'quadric', radius,
        beta), measured on its own `QuadricSurface` whatever `patches` says.
    points : (m, 3) float, optional
        Points to time (repeated up to `timing_points` if fewer); default `timing_points`
        points sampled near the target.
    sample : int
        Nodes to hold out in all.
    seed : int
        Seeds the held-out nodes and the sampled points.
    flip : bool
        Reverse the target's orientation.
    timing_points, repeat, budget, min_time
        Sampled points to time, and the timing's repeats and seconds (`throughput`).
    progress : callable(str), optional
        Receives a line per step (the CLI logs them on stderr).
    patches : dict, optional
        Measure the surface `diffsurf project` answers with: a `PatchedSurface` (smooth
        patches, the facets at sharp edges and where a patch cannot answer, the guard) of
        these settings: `feature_angle` (degrees, None or 180: one patch), `tags` (one per
        facet) and `smooth_tags`. None: one `DiffuseSurface` per setting (the bare method).

    Returns
    -------
    Tuning
    """
    say = progress or (lambda message: None)
    nodes = np.asarray(nodes, dtype=np.float64)
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    # coincident nodes are one node (a triangle soup, an STL's facets unmerged): holding out
    # one of them would leave its copies in the fit, and no node of a soup is interior
    distinct, inverse = np.unique(nodes, axis=0, return_inverse=True)
    if len(distinct) < len(nodes):
        say(f"merged {len(nodes) - len(distinct)} coincident nodes")
        nodes, faces = distinct, [inverse.ravel()[f] for f in faces]
    corners = [facet_corners(f) for f in faces]  # mid-side nodes are never held out
    if not settings:
        raise ValueError("no settings to tune")
    rng = np.random.default_rng(seed)
    spacing = node_spacing(nodes)
    separation = SEPARATION * max(support_radius(o) for o in settings.values())
    batches = holdout_batches(nodes, corners, spacing, separation, sample, rng)
    held = np.concatenate(batches) if batches else np.zeros(0, dtype=np.int64)
    if not len(held):
        raise ValueError("the target has no interior node to hold out")
    say(f"leave-one-out: {len(held)} held-out nodes in {len(batches)} batches "
        f"(pairwise > {separation:g} spacings apart)")
    sampled = points is None
    if sampled:
        points = sample_near_facets(nodes, corners, timing_points, rng, spacing)
        say(f"timing on {len(points)} points sampled within one spacing of the facets")
    points = np.asarray(points, dtype=np.float64)
    # a few hundred points take a millisecond, about the size of the per-call overheads and of
    # their jitter: time at least `timing_points` by repeating the user's points
    timed = points
    if 0 < len(points) < timing_points:
        timed = np.tile(points, (-(-timing_points // len(points)), 1))[:timing_points]
        say(f"timing on {len(points)} points repeated to {len(timed)}")
    h = spacing[held]
    estimates = []
    for name, options in settings.items():
        if options.get("method") == "quadric":  # its own fit, on the whole target
            surface = _quadric(nodes, faces, options, flip)
            gap, status = leave_one_out(nodes, faces, options, batches, flip=flip,
                                        full_normals=surface.normals)
        elif patches is None:
            surface = DiffuseSurface(nodes, faces, flip=flip, **options)
            gap, status = leave_one_out(nodes, faces, options, batches, frame=surface.frame,
                                        flip=flip)
        else:
            surface = _patched(nodes, faces, options, flip, patches)
            gap, status = leave_one_out(nodes, faces, options, batches, flip=flip,
                                        patches=patches)
        good = status < OUTSIDE
        error = np.where(good, np.abs(gap), np.nan)
        rate, result = throughput(surface, timed, repeat, budget, min_time)
        e = Estimate(name=name, options=dict(options), frame=getattr(surface, "frame", "local"),
                     loo_rms=_rms(error[good]),
                     loo_max=float(error[good].max()) if good.any() else np.nan,
                     loo_rms_h=_rms(error[good] / h[good]),
                     loo_max_h=float(np.max(error[good] / h[good])) if good.any() else np.nan,
                     loo_bad=int((~good).sum()), rate=rate, points=len(points),
                     bad=int((result.status[:len(points)] >= OUTSIDE).sum()),
                     loo_error=error)
        say(f"{name}: LOO RMS {e.loo_rms:.3g} ({e.loo_rms_h:.3g} h), {e.rate:,.0f} points/s")
        estimates.append(e)
    return Tuning(estimates, recommend(estimates), held, batches, h, sampled)


def plot(tuning: Tuning, title: str = ""):
    """The trade curve: LOO RMS error against points/s, log axes, a labelled point per
    setting (the recommended one ringed). Returns a matplotlib Figure (no pyplot state)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for e in tuning.estimates:
        if not (np.isfinite(e.loo_rms) and e.loo_rms > 0):
            continue
        ax.scatter([e.rate], [e.loo_rms], s=40, zorder=3)
        if e.name == tuning.recommended:
            ax.scatter([e.rate], [e.loo_rms], s=160, facecolors="none", edgecolors="k", zorder=2,
                       label=f"recommended: {e.name} (the fastest within {TOLERANCE:g}x the "
                             f"best error,\namong the presets with the fewest failures)")
        ax.annotate(e.name, (e.rate, e.loo_rms), textcoords="offset points", xytext=(6, 4))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("throughput (points/s)")
    ax.set_ylabel("leave-one-out RMS |gap| (target units)")
    ax.set_title(title or f"speed/accuracy trade (recommended: {tuning.recommended})")
    ax.grid(True, which="both", alpha=0.3)
    if tuning.recommended is not None:  # below the axes: it never covers a point
        fig.legend(loc="outside lower center", fontsize="small")
    return fig
