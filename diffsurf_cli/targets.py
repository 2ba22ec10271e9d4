"""A target from a mesh file: its surface nodes and facets (`read_surface`), the surface of the
method asked for, with its engine options or preset (`build_surface`, `surface_from_file`),
and the check for contactors that are the target's own nodes (`coincident`).

What it reads and builds is logged on the ``diffsurf`` logger (the command line prints it on
stderr); errors are ValueError (the options, the geometry) and `io.ReadError` (the file).
"""
from __future__ import annotations

import logging
import warnings

import numpy as np

from . import io
from .io.boundary import facing_inward
from .mls.frame import cell_faces, facet_area_vectors, facet_corners
from .mls.surface import DiffuseSurface
from .patches.segment import FEATURE_ANGLE_DEG, consistent_winding
from .presets import engine_options
from .projection import InsideOutWarning

# The facet method and the patches are imported where they are used, so a plain `project`
# starts without them.

log = logging.getLogger("diffsurf")

#: The surfaces `build_surface` makes.
METHODS = ("diffuse", "facet", "quadric")

#: The stages of a target's setup, in their order, as a ``progress`` callback of
#: `surface_from_file` (`read_surface`, `build_surface`, `PatchedSurface`) is called with
#: them: each names the work that starts (a surface skips those it has not; the command line
#: adds 'engine', the compiled engine it builds before the projection).
STAGES = ("reading", "winding", "node identity", "edges and patches", "facets", "edge classes",
          "rings", "guard bounds", "curved cells", "diffuse surface", "engine")


def read_surface(path: str, zone: str | None = None, *, progress=None):
    """Read a target mesh: its surface nodes and facet blocks.

    Parameters
    ----------
    path : str
        A mesh file meshio reads (`io.read_target`).
    zone : str, optional
        Keep only this Gmsh physical group, cell set, node set or Abaqus *SURFACE.
    progress : callable, optional
        Called with the name of each stage as it starts ('reading', 'winding': `STAGES`).

    Returns
    -------
    target : io.Target
        The file's points, surface cells and, in ``target.tags``, their face or region tags
        (per block, or None).
    nodes : (n, 3) float
        The surface nodes, ``target.points[target.nodes]``.
    faces : list of (f_b, k) int
        Facet blocks indexing `nodes`; higher-order cells keep their mid-side nodes (the
        diffuse surface gives them their cells' normals; the facet method uses the corners).

    Raises
    ------
    io.ReadError
        The file is missing, unreadable or holds no surface.
    """
    if progress is not None:
        progress("reading")
    target = io.read_target(path, zone=zone)
    for kind, count in sorted(target.ignored.items()):
        log.info("%s: ignored %d %s cells (not surface cells)", path, count, kind)
    for kind, count in sorted(target.boundary.items()):
        log.info("%s: the target is the boundary of %d %s cells", path, count, kind)
    nodes = target.points[target.nodes]
    faces = [np.searchsorted(target.nodes, f) for f in cell_faces(target.cells)]
    faces, target.tags, dropped = drop_degenerate(nodes, faces, target.tags)
    if dropped:
        log.info("%s: dropped %d degenerate facets (zero area: repeated or collinear "
                 "corners)", path, dropped)
    if progress is not None:
        progress("winding")
    faces, flipped, undecided = consistent_winding(nodes, faces)
    if flipped:
        log.info("%s: reversed %d facets wound against their neighbours (the orientation of "
                 "the larger part of each surface kept)", path, flipped)
    if undecided:
        log.warning("warning: %s: %d facets lie on surfaces no orientation fits (a "
                    "non-orientable join): their gaps' signs may be wrong", path, undecided)
    log.info("%s: target of %d nodes, %d facets%s", path, len(nodes),
             sum(len(f) for f in faces), f" (zone {zone!r})" if zone else "")
    return target, nodes, faces


#: A facet whose area is below this fraction of its longest corner distance squared has
#: none: its corners repeat a node or lie on a line.
DEGENERATE_AREA = 1e-12


def drop_degenerate(nodes, faces, tags=None):
    """The facet blocks without their zero-area facets (a triangle [0, 0, 1] or [2, 3, 2], or
    collinear corners: as a chord through the target they would answer points inside it with
    a wrong 'open'), and the tags per block kept in step. Returns (faces, tags, dropped)."""
    kept_faces, kept_tags, dropped = [], None if tags is None else [], 0
    for b, f in enumerate(faces):
        f = np.asarray(f)
        corners = nodes[facet_corners(f)]
        area = np.linalg.norm(facet_area_vectors(nodes, [f]), axis=1)
        span = np.max(np.linalg.norm(corners[:, :, None] - corners[:, None, :], axis=3),
                      axis=(1, 2), initial=0.0)
        keep = area > DEGENERATE_AREA * span**2
        dropped += int((~keep).sum())
        kept_faces.append(f[keep])
        if tags is not None:
            kept_tags.append(np.asarray(tags[b])[keep])
    return kept_faces, kept_tags, dropped


def _facet_count(faces) -> int:
    """What ``sum(len(f) for f in faces)`` counts, without a Python loop over the rows of one
    (F, k) array of facets (each row counts its k entries: F * k, nonzero where it has
    facets of any corner), block by block otherwise."""
    if isinstance(faces, np.ndarray) and faces.ndim >= 2:
        return faces.shape[0] * faces.shape[1]
    return sum(len(f) for f in faces)


def build_surface(nodes, faces, *, method: str = "diffuse", preset: str = "default",
                  feature_angle: float | None = FEATURE_ANGLE_DEG, tags=None,
                  smooth_tags: bool = False, flip: bool = False, progress=None, **options):
    """The surface of a target's nodes and facets, as ``diffsurf project`` builds it.

    Parameters
    ----------
    nodes : (n, 3) float
        Surface nodes.
    faces : list of (f_b, k) int
        Facet blocks indexing `nodes` (`read_surface`).
    method : {'diffuse', 'facet', 'quadric'}
        'facet': the faceted target itself (`FacetSurface`, its corners). 'quadric': moving
        algebraic quadrics fitted to the nodes' positions and normals (`QuadricSurface`), for
        smooth coarse curved targets (a few elements per quarter circle); no patches and no
        guard, so not for targets with creases; options: radius, beta.
    preset : {'fast', 'default', 'normals'}
        Engine options of the diffuse surface (`presets.PRESETS`), overridden by `options`.
    feature_angle : float or None
        Degrees. Below 180: the diffuse surface per smooth patch (`PatchedSurface`, bounded by
        edges sharper than this, by `tags` and by open boundaries); 180 or None: one diffuse
        surface over the whole target (a `PatchedSurface` of one patch). Either way the facets
        answer where the diffuse surface cannot, and guard every diffuse answer.
    tags : (f,) int, optional
        Face or region tag of each facet (blocks one after the other): patches never join
        facets of different tags.
    smooth_tags : bool
        The tags are CAD faces (Gmsh geometrical entities): no edge inside one is a feature.
    flip : bool
        Reverse the orientation (+normal into the target).
    progress : callable, optional
        Called with the name of each stage of the build as it starts (`STAGES`: 'facets' for
        the facet method, 'diffuse surface' for a cloud of nodes, `PatchedSurface`'s
        otherwise): a caller's sign of life on a large target (the command line's line on a
        terminal).
    **options
        `DiffuseSurface` options (basis, weight, support, radius, k, frame, recentre, ...);
        ignored by the facet method.

    Returns
    -------
    PatchedSurface, FacetSurface or QuadricSurface (a DiffuseSurface for nodes without
    facets)

    Raises
    ------
    ValueError
        Unknown method, preset or option value, or a target the surface cannot be built on.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: expected one of {', '.join(METHODS)}")
    if method == "quadric":
        from .mls.quadric import QuadricSurface

        unknown = sorted(set(options) - {"radius", "beta"})
        if unknown or preset not in (None, "default") or (
                feature_angle is not None and feature_angle != FEATURE_ANGLE_DEG):
            given = unknown + (["preset"] if preset not in (None, "default") else []) + (
                ["feature_angle"] if feature_angle not in (None, FEATURE_ANGLE_DEG) else [])
            raise ValueError(f"the quadric method takes radius and beta only, not "
                             f"{', '.join(given)}")
        if progress is not None:
            progress("diffuse surface")
        kwargs = {k: v for k, v in options.items() if v is not None}
        surf = QuadricSurface(nodes, faces, flip=flip, **kwargs)
        log.info("quadric fit to positions and normals: radius %g, beta %g", surf.radius,
                 surf.beta)
        sharp = quadric_creases(surf)
        if sharp:
            log.warning("warning: %d edges of the target are creases (sharper than %g° and no "
                        "bend of a coarse curve): the quadric method rounds them, and near them "
                        "its answers are not the facets' (the diffuse method keeps them)",
                        sharp, FEATURE_ANGLE_DEG)
        return surf
    engine = engine_options(preset, **options)
    if method == "facet":
        from .facet.surface import FacetSurface

        if progress is not None:
            progress("facets")
        return FacetSurface(nodes, [facet_corners(f) for f in faces], flip=flip)
    from .patches.surface import PatchedSurface

    if not len(faces) or not _facet_count(faces):  # a cloud of nodes: no facets, no guard
        if progress is not None:
            progress("diffuse surface")
        surf = DiffuseSurface(nodes, faces, flip=flip, **engine)
    elif feature_angle is not None and feature_angle < 180:
        surf = PatchedSurface(nodes, faces, feature_angle=feature_angle, tags=tags,
                              smooth_tags=smooth_tags, flip=flip, progress=progress, **engine)
        log.info("%d smooth patch%s (feature angle %g°%s)", surf.npatches,
                 "es" if surf.npatches > 1 else "", feature_angle,
                 ", face tags" if tags is not None else "")
    else:  # one diffuse surface over the whole target, guarded by its facets
        surf = PatchedSurface(nodes, faces, feature_angle=None, flip=flip, progress=progress,
                              **engine)
    if isinstance(surf, PatchedSurface) and surf.geometry_free:  # issue 34: refined, no CAD
        log.info("%d nodes add no geometry (in the plane of coplanar facets, or on the line of "
                 "a straight edge: a refinement without the CAD): the smooth surface is fitted "
                 "without them, over the facets they cut", surf.geometry_free)
    log.info("frame: %s; basis %s, weight %s, support %s", surf.frame, surf.basis, surf.weight,
             surf.support)
    return surf


def quadric_creases(surf) -> int:
    """The creases (`segment.creases`) of a QuadricSurface's target, which it rounds."""
    from .patches.segment import creases

    return int(np.count_nonzero(creases(surf.nodes, [facet_corners(f) for f in surf.faces
                                                     if len(f)])))


def surface_from_file(path: str, *, zone: str | None = None, method: str = "diffuse",
                      preset: str = "default", feature_angle: float | None = FEATURE_ANGLE_DEG,
                      flip: bool = False, progress=None, **options):
    """Read a target mesh and build its surface (`read_surface`, then `build_surface` with the
    file's face or region tags).

    Parameters
    ----------
    path : str
    zone : str, optional
    method, preset, feature_angle, flip, **options
        As `build_surface`: ``surface_from_file(path)`` is the surface ``diffsurf project``
        builds by default; ``feature_angle=180`` one `DiffuseSurface` over the whole target.
    progress : callable, optional
        Called with the name of each stage as it starts, reading included (`STAGES`).

    Returns
    -------
    target : io.Target
        The file's points and cells: its point indices are the file's numbering
        (``target.nodes[i]`` is the file point of surface node i).
    surface : DiffuseSurface, PatchedSurface or FacetSurface

    Raises
    ------
    io.ReadError
        The file cannot be read as a target.
    ValueError
        As `build_surface`, its message prefixed with `path`.

    Examples
    --------
    >>> from diffsurf_cli import surface_from_file
    >>> target, surface = surface_from_file("sample_meshes/cylinder.msh", preset="fast")
    """
    target, nodes, faces = read_surface(path, zone, progress=progress)
    tags = np.concatenate(target.tags) if target.tags is not None else None
    try:
        # a closed target wound inside out is said on the log, as the file's other warnings
        # (the command line's --flip-normals is the API's flip=True)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", InsideOutWarning)
            surface = build_surface(nodes, faces, method=method, preset=preset,
                                    feature_angle=feature_angle, tags=tags,
                                    smooth_tags=target.faces_tagged, flip=flip,
                                    progress=progress, **options)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    for w in caught:
        if isinstance(w.message, InsideOutWarning):
            log.warning("warning: %s: %s", path, w.message.text("--flip-normals (flip=True)"))
        else:  # any other warning, as it was
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return target, surface


def coincident(points, nodes) -> int:
    """How many contactors are exactly at one of the target's nodes.

    Such contactors are the target's own nodes (a two-body mesh given whole as both target and
    contactors): their gap is that of the target to itself.

    Parameters
    ----------
    points : (m, 3) float
        Contactors.
    nodes : (n, 3) float
        Target nodes.

    Returns
    -------
    int
        Rows of `points` equal to a row of `nodes` (-0.0 equals 0.0). Sorted on x, then the
        rows that share an x are compared whole: O((m + n) log n).
    """
    points = np.asarray(points, dtype=np.float64) + 0.0  # -0.0 equals 0.0
    nodes = np.asarray(nodes, dtype=np.float64) + 0.0
    if not len(points) or not len(nodes):
        return 0
    order = np.argsort(nodes[:, 0], kind="stable")
    xs = nodes[order, 0]
    lo = np.searchsorted(xs, points[:, 0], "left")
    hi = np.searchsorted(xs, points[:, 0], "right")
    rows = np.flatnonzero(hi > lo)
    found = np.zeros(len(rows), dtype=bool)
    for k in range(int((hi - lo)[rows].max(initial=0))):
        live = lo[rows] + k < hi[rows]
        at = order[np.minimum(lo[rows] + k, len(order) - 1)]
        found |= live & np.all(nodes[at] == points[rows], axis=1)
    return int(found.sum())


#: Significant decimal digits of the node spacing below which the geometry is called lost:
#: a coordinate's rounding is then more than a millionth of a spacing.
PRECISION_DIGITS = 6


def precision_digits(points, nodes, spacing) -> float:
    """Decimal digits of the smallest node spacing that doubles keep at the largest
    coordinate of the target and the contactors: log10(spacing / ulp(largest)). Below
    `PRECISION_DIGITS` the input itself has lost the geometry (a sphere of radius 1 moved by
    1e15 has none left): no computation can give its gaps back; translate the model near the
    origin."""
    coords = [np.abs(np.asarray(nodes, dtype=np.float64)).max(initial=0.0)]
    pts = np.asarray(points, dtype=np.float64)
    finite = pts[np.all(np.isfinite(pts), axis=1)] if pts.size else pts
    coords.append(np.abs(finite).max(initial=0.0))
    top = max(coords)
    spacing = float(np.min(spacing)) if np.size(spacing) else 0.0
    if not spacing > 0:
        return float("inf")
    return float(np.log10(spacing / np.spacing(top))) if top > 0 else float("inf")


def outward_faces(points, faces, cells) -> np.ndarray:
    """A target from a face of a volume body: `faces` wound out of the body they bound.

    An FE model's contact face is a set of its body's boundary faces (scikit-fem's
    ``mesh.facets[:, ids].T``, a face set of the deck); their winding is whatever the mesher
    gave, and a target's normal must point out of its body (the gap is positive outside it).
    Each face is matched to the volume cell that holds all its corners, and reversed where
    its right-hand normal points towards that cell's centroid, as `io.boundary` winds the
    boundary of volume cells read from a file. Any node ordering of the cells will do: only
    their node sets and centroids are used.

    Parameters
    ----------
    points : (n, 3) float
        The body's nodes.
    faces : (f, k) int
        Faces (k = 3 or 4 corners in cyclic order), node indices into `points`.
    cells : (c, j) int
        The body's volume cells (any type, any node order; rows padded with -1 are fine).

    Returns
    -------
    (f, k) int64
        The faces, each wound out of the body (a copy).

    Raises ValueError naming the first face that no cell holds (not a face of this body) or
    that two cells share (inside it).
    Where the faces came wound into the body, `wound_inward` says how many.
    """
    faces = np.array(faces, dtype=np.int64, copy=True)
    inward = wound_inward(points, faces, cells)
    faces[inward] = faces[inward][:, ::-1]
    return faces


def wound_inward(points, faces, cells) -> np.ndarray:
    """(f,) bool: the faces of a body (`outward_faces`' arguments) whose right-hand normal
    points into it, towards the centroid of the volume cell that holds them: a target so
    wound gives negative gaps outside its body. ValueError for a face no cell holds."""
    import scipy.sparse as sp

    points = np.asarray(points, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    cells = np.asarray(cells, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] not in (3, 4):
        raise ValueError(f"faces of shape {faces.shape}: expected (f, 3) or (f, 4) corners")
    if cells.ndim != 2 or not len(cells):
        raise ValueError(f"cells of shape {cells.shape}: expected (c, j) volume cells")
    n = len(points)
    for name, arr in (("faces", faces), ("cells", cells)):
        if arr.size and arr.max() >= n:
            raise ValueError(f"{name} name node {int(arr.max())}, past the {n} points")
    if faces.size and faces.min() < 0:
        raise ValueError("faces name a negative node")
    if not len(faces):
        return np.zeros(0, bool)
    # the cell holding each face: the one sharing all of its corners (face-node by
    # node-cell incidence: a count of shared nodes, k for the holder)
    real = cells >= 0
    rows = np.repeat(np.arange(len(cells)), real.sum(axis=1))
    C = sp.csr_matrix((np.ones(len(rows)), (rows, cells[real])), shape=(len(cells), n))
    k = faces.shape[1]
    Fm = sp.csr_matrix((np.ones(faces.size), (np.repeat(np.arange(len(faces)), k),
                                              faces.ravel())), shape=(len(faces), n))
    shared = (Fm @ C.T).tocsr()
    shared.data = (shared.data >= k).astype(np.float64)
    shared.eliminate_zeros()
    holders = np.diff(shared.indptr)
    for bad, what in ((holders == 0, "is held by no cell: not a face of this body"),
                      (holders > 1, "is shared by two cells: inside the body, not on its "
                                    "boundary")):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"face {i} (nodes {faces[i].tolist()}) {what}")
    holder = shared.indices[shared.indptr[:-1]]
    counts = real.sum(axis=1)
    centroid = (np.where(real[..., None], points[np.where(real, cells, 0)], 0.0).sum(axis=1)
                / counts[:, None])[holder]
    # the test `io.boundary` winds the boundary of a file's volume cells by
    return facing_inward(points, faces, k, centroid)
