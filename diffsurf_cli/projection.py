"""What every surface returns: the projection's result (`Projection`), the frozen pairing
(`Patch`), the status and reason codes [33], and the checks of points and target nodes.

The diffuse surface (`mls`), the faceted target (`facet`) and the patched surface
(`patches`) all answer with these, so none of them imports another for its result type.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from . import tol
from ._codes import REASONS, STATUS

#: Status codes [33] and reason codes, by code: the compiled modules' own (`_codes.pxd`),
#: read from the extension, never copied.
#:
#: Status: 'open', 'contact', 'penetration', 'outside' (no usable support), 'failed'.
#: Reasons: 'ok' for the other statuses; 'bad-point' a contactor with NaN or inf; 'few-nodes'
#: fewer support nodes than basis terms; 'ill-conditioned' a support that cannot determine the
#: basis (collinear or one-sided nodes: reciprocal condition number below `tol.RCOND_MIN`);
#: 'off-target' a proximal point past the target's edge or beyond every support node;
#: 'no-convergence' Newton [30] did not converge; 'recentre' re-centring did not settle;
#: 'steep' the support holds a node where the target turns vertical or folds back over the
#: frame (`frame.FOLD_SLOPE_DEG`): X3 = f(X1, X2) cannot represent it there; 'guard' (with an
#: answered status) the facets answered, because the diffuse answer differed from theirs by
#: more than smoothing them can explain (`patches.surface`, method.md "The facets bound the
#: smooth surface").

OPEN, CONTACT, PENETRATION, OUTSIDE, FAILED = (STATUS.index(s) for s in (
    "open", "contact", "penetration", "outside", "failed"))
(OK, BAD_POINT, FEW_NODES, ILL_CONDITIONED, OFF_TARGET, NO_CONVERGENCE, NOT_SETTLED, STEEP,
 GUARD) = (REASONS.index(r) for r in ("ok", "bad-point", "few-nodes", "ill-conditioned",
                                       "off-target", "no-convergence", "recentre", "steep",
                                       "guard"))


@dataclass
class Patch:
    """The frozen pairing of a chunk of contactors: what the paper holds fixed [§4.2].

    origin : (m, 3) float  reference point (basis centre) of each local approximation
    axes : (m, 3, 3) float  rows e1, e2, e3 of each diffuse frame
    radius : (m,) float     R, the radius of the domain of influence
    spacing : (m,) float    local node spacing h (tolerances and 'outside' are relative to it)
    index : (m, K) int      support node indices, -1 padded
    reduced : (m,) int8     the reduced basis fitted (an index into basis.REDUCED), -1 the
                            full basis; None: not known (the full basis)
    direction : (m,) float  the angle of its a axis from e1 in the frame (NaN: none, a = s)
    """

    origin: np.ndarray
    axes: np.ndarray
    radius: np.ndarray
    spacing: np.ndarray
    index: np.ndarray
    reduced: np.ndarray | None = None
    direction: np.ndarray | None = None

    def take(self, rows) -> Patch:
        """The pairing of contactors `rows` (indices or a slice)."""
        def sub(a):
            return None if a is None else np.asarray(a)[rows]

        return Patch(sub(self.origin), sub(self.axes), sub(self.radius), sub(self.spacing),
                     sub(self.index), sub(self.reduced), sub(self.direction))


@dataclass
class Pairing:
    """What a contact element holds fixed within a step, for any surface (`Contact.pairing`;
    `contact(..., pairing=...)` takes it back).

    source : (m,) int   what answered each contactor: patch p of a PatchedSurface (0 for a
                        DiffuseSurface), -1 the facets (a FacetSurface, or a PatchedSurface's
                        facets: a sharp edge, the guard), -2 nothing, -3 a PatchedSurface's
                        second-order cell (`element.cell`)
    patch : Patch or None   the frozen frames, supports (node indices of the answering patch's
                        surface) and radii of the rows answered by a diffuse surface
    facet : (m,) int or None   the facet of the rows the facets answered, the cell (its facet)
                        of those a cell answered (-1 elsewhere)
    made_on : str or None   the type of the surface that made it ('DiffuseSurface',
                        'FacetSurface', 'PatchedSurface'): another type refuses it (its
                        fields mean other things there); None: not known (built by hand)
    """

    source: np.ndarray
    patch: Patch | None = None
    facet: np.ndarray | None = None
    made_on: str | None = None

    def __len__(self) -> int:
        return len(np.asarray(self.source).reshape(-1))

    def take(self, rows) -> Pairing:
        """The pairing of contactors `rows` (indices or a slice)."""
        return Pairing(np.asarray(self.source)[rows],
                       None if self.patch is None else self.patch.take(rows),
                       None if self.facet is None else np.asarray(self.facet)[rows],
                       self.made_on)


@dataclass(frozen=True)
class Column:
    """One output column of a projection (`COLUMNS`): its name in tables, the `Projection`
    field it is read from, and which component of an (m, 3) field (None: an (m,) field).
    Mesh outputs hold the components of a field as one vector named after the field
    (``normal``, ``proximal_point``), the points' as the mesh's points."""

    name: str
    field: str
    component: int | None = None


#: The output columns of a projection, in order: the one declaration every writer reads
#: (`Projection.columns`, the command line's tables and meshes, the Dask partitions, the
#: check of a result fed back as input). A column whose field is None on a result is left
#: out of it (terms: not on the facets; facet_gap: not on a DiffuseSurface). docs/outputs.md
#: says what each holds.
COLUMNS = (
    Column("x", "points", 0), Column("y", "points", 1), Column("z", "points", 2),
    Column("gap", "gap"),
    Column("nx", "normal", 0), Column("ny", "normal", 1), Column("nz", "normal", 2),
    Column("px", "proximal_point", 0), Column("py", "proximal_point", 1),
    Column("pz", "proximal_point", 2),
    Column("status", "status"), Column("support", "support"),
    Column("iterations", "iterations"), Column("rcond", "rcond"), Column("reason", "reason"),
    Column("terms", "terms"),
    Column("facet_gap", "facet_gap"),
)

#: The words of the coded columns (tables write the words, meshes the codes).
LABELS = {"status": STATUS, "reason": REASONS}

#: The arrays the compiled passes write, one row per contactor, declared once: name ->
#: (dtype, shape of a row, value before the pass). Each pass points its C record at them by
#: these names (`mls._projection.record_of`, `Record` in `_projection.pxd`) and checks their
#: dtype and shape there. `RECORD`: every pass's (the `Projection` fields, and `overflow`:
#: a support wider than the pass's scratch, run again); `PAIRING_RECORD`: a diffuse
#: surface's frozen pairing (`Patch`); `PASS_RECORD`: the patched pass's (what answered, the
#: facets' answer, the curved cell's).
RECORD = {
    "gap": (np.float64, (), np.nan),
    "normal": (np.float64, (3,), np.nan),
    "proximal_point": (np.float64, (3,), np.nan),
    "status": (np.int8, (), FAILED),
    "reason": (np.int8, (), OK),
    "support": (np.int64, (), 0),
    "iterations": (np.int64, (), 0),
    "rcond": (np.float64, (), np.nan),
    "curvature": (np.float64, (2,), np.nan),
    "terms": (np.int8, (), 0),
    "overflow": (np.uint8, (), 0),
}
PAIRING_RECORD = {
    "origin": (np.float64, (3,), np.nan),
    "axes": (np.float64, (3, 3), np.nan),
    "radius": (np.float64, (), np.nan),
    "spacing": (np.float64, (), np.nan),
    "direction": (np.float64, (), np.nan),
    "reduced": (np.int8, (), -1),
    "count": (np.int64, (), 0),  # the support's nodes the engine wrote (not a Patch field)
}
PASS_RECORD = {
    "source": (np.int64, (), -2),  # nothing answered (`Pairing.source`)
    "facet": (np.int64, (), -1),
    "facet_gap": (np.float64, (), np.nan),
    "facet_normal": (np.float64, (3,), np.nan),
    "guard_gap": (np.float64, (), np.nan),
    "support_floor": (np.float64, (), 0.0),
    "cell": (np.int64, (), -1),
    "cell_param": (np.float64, (2,), np.nan),
}


def allocate(m: int, *extra: dict) -> dict[str, np.ndarray]:
    """A pass's output arrays for m contactors: `RECORD`'s and those of the `extra` tables
    (`PAIRING_RECORD`, `PASS_RECORD`), each filled with its value before the pass."""
    return {name: np.full((m, *shape), fill, dtype)
            for table in (RECORD, *extra) for name, (dtype, shape, fill) in table.items()}


def recorded(out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The `Projection` fields among a pass's arrays (`allocate`): all but the pass's own
    bookkeeping (overflow) and the pairing's (`Patch`)."""
    return {name: a for name, a in out.items()
            if name != "overflow" and name not in PAIRING_RECORD}


@dataclass
class Projection:
    """Contact quantities of each contactor on the diffuse surface (arrays, one row per point).

    points : (m, 3) float           the contactors x^c
    gap : (m,) float                normal gap g [32], > 0 open, < 0 penetration
    normal : (m, 3) float           unit normal ν [29] at the proximal point, out of the target
    proximal_point : (m, 3) float   x^d [25]
    status : (m,) int8              index into `STATUS`
    support : (m,) int              number of support nodes with positive weight
    iterations : (m,) int           Newton iterations (summed over re-centrings)
    rcond : (m,) float              reciprocal condition number of the fit: a lower bound
                                    rcond_F = 1/(‖R‖_F ‖R⁻¹‖_F) on σmin/σmax of the
                                    equilibrated W^½P (within a factor of the basis size),
                                    exact where that bound cannot decide against
                                    tol.RCOND_MIN; so rcond >= tol.RCOND_MIN exactly when
                                    σmin/σmax is (see tol.py)
    curvature : (m, 2) float        principal curvatures κ1 ≥ κ2 of the local fit at x^d,
                                    > 0 where the surface bends away from ν (convex, as a
                                    sphere seen from outside)
    reason : (m,) int8              index into `REASONS`: why a point is outside or failed
    terms : (m,) int8               basis terms fitted: the basis's size, fewer where the
                                    support could not determine it and the largest reduced
                                    basis it could was fitted (`basis.REDUCED`: a strip two
                                    nodes wide, a row of nodes), 0 where none was (not
                                    even a line; or the facets answered: PatchedSurface)
    patch : Patch or None           the frozen pairing of the diffuse surface
                                    (``project(..., keep_patch=True)``), None otherwise

    What some surfaces answer besides (None where the surface that answered does not):

    alpha : (m, nterms) float       the fit's coefficients α [17]: the full basis in the
                                    pairing's scaled frame, centred at the contactor (NaN
                                    where not answered): DiffuseSurface with ``keep_patch``
    facet : (m,) int                the facet of each proximal point (-1: none): FacetSurface;
                                    the facets' own answer on PatchedSurface
    param : (m, 2) float            the facet's parameters ξ at the proximal point:
                                    FacetSurface
    source : (m,) int               what answered each contactor: patch p (>= 0), -1 the
                                    facets (a sharp edge or corner, a patch that cannot answer,
                                    the guard), -2 nothing, -3 a second-order cell:
                                    PatchedSurface (`patches.surface.FACETS`, `NOTHING`,
                                    `CELLS`); the contact element sets it too
    facet_gap : (m,) float          the facets' own gap of each contactor (the faceted answer,
                                    whatever answered): PatchedSurface; FacetSurface (its
                                    gap, the same array)
    facet_normal : (m, 3) float     the facets' own normal there: PatchedSurface
    guard_gap : (m,) float          the faceted gap the guard measured the answer from:
                                    facet_gap, but where the faceted foot is on an open
                                    edge, the height over the foot facet's plane:
                                    PatchedSurface
    support_floor : (m,) float      the least spacing the answering patch's support took
                                    (the facets' under the contactor on its home patch;
                                    0 elsewhere): PatchedSurface
    cell : (m,) int                 the facet whose curved cell answered (-1 elsewhere):
                                    PatchedSurface
    cell_param : (m, 2) float       that cell's closest point's parameters (NaN elsewhere):
                                    PatchedSurface
    pairing : Pairing or None       what a contact element holds fixed within a step
                                    (`Contact.pairing`): set by the element, not the surfaces
    """

    points: np.ndarray
    gap: np.ndarray
    normal: np.ndarray
    proximal_point: np.ndarray
    status: np.ndarray
    support: np.ndarray
    iterations: np.ndarray
    rcond: np.ndarray
    curvature: np.ndarray
    reason: np.ndarray
    terms: np.ndarray | None = None
    patch: Patch | None = field(default=None, repr=False)
    alpha: np.ndarray | None = field(default=None, repr=False)
    facet: np.ndarray | None = None
    param: np.ndarray | None = None
    source: np.ndarray | None = None
    facet_gap: np.ndarray | None = None
    facet_normal: np.ndarray | None = None
    guard_gap: np.ndarray | None = None
    support_floor: np.ndarray | None = None
    cell: np.ndarray | None = None
    cell_param: np.ndarray | None = None
    pairing: Pairing | None = field(default=None, repr=False)

    @property
    def status_names(self) -> np.ndarray:
        return np.asarray(STATUS, dtype=object)[self.status]

    @property
    def reason_names(self) -> np.ndarray:
        return np.asarray(REASONS, dtype=object)[self.reason]

    @property
    def thin(self) -> np.ndarray:
        """Rows whose support cannot carry the basis (too few nodes, or ill-conditioned)."""
        return (self.reason == FEW_NODES) | (self.reason == ILL_CONDITIONED)

    def columns(self) -> dict[str, np.ndarray]:
        """The output columns (`COLUMNS`, in order) of the fields this result holds: name ->
        (m,) array, a view of the field's."""
        out = {}
        for c in COLUMNS:
            values = getattr(self, c.field)  # a declared field, by its declared name
            if values is not None:
                out[c.name] = values if c.component is None else values[:, c.component]
        return out


class NearestNode:
    """The nearest target node of a contactor, and whether it is far from every node: farther
    than `radius` local node spacings (the support radius R) from its nearest node. Built on
    first use (a k-d tree of the nodes), for the contactors that got no answer."""

    def __init__(self, nodes: np.ndarray, spacing: np.ndarray, radius: float):
        self.nodes, self.spacing, self.radius = nodes, spacing, float(radius)
        self._tree = None

    def far(self, points: np.ndarray) -> np.ndarray:
        """(m,) bool: each point farther than R = radius x spacing from its nearest node."""
        if self._tree is None:
            from scipy.spatial import cKDTree

            self._tree = cKDTree(self.nodes)
        dist, near = self._tree.query(points)
        return dist > self.radius * self.spacing[np.minimum(near, len(self.nodes) - 1)]


def mark_far(res: Projection, nearest: NearestNode) -> np.ndarray:
    """Every contactor without an answer (status outside or failed; a NaN contactor aside)
    that is far from every node (`NearestNode.far`: no node within the support radius) is
    'outside' with reason 'off-target' (docs: "far from every node"), whatever the verdict
    of the support its search found (too few nodes, steep, ...), and NaN in gap, normal,
    proximal point, rcond and curvature: nothing was fitted there that means anything.
    Answered contactors are left as they are. Returns the rows marked."""
    rows = np.flatnonzero(((res.status == OUTSIDE) | (res.status == FAILED))
                          & (res.reason != BAD_POINT))
    if not len(rows):
        return rows
    rows = rows[nearest.far(res.points[rows])]
    res.status[rows], res.reason[rows] = OUTSIDE, OFF_TARGET
    for name in ("gap", "normal", "proximal_point", "rcond", "curvature"):
        getattr(res, name)[rows] = np.nan
    if res.terms is not None:
        res.terms[rows] = 0
    return rows


def as_points(points, name="points") -> np.ndarray:
    """`points` as a float (n, 3) array; ValueError naming `name` for any other shape."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {arr.shape}")
    return arr


def as_target_nodes(nodes) -> np.ndarray:
    """Target nodes as a float (n, 3) array, refused (ValueError) when a coordinate is NaN or
    inf or beyond `tol.COORDINATE_MAX` (fourth powers of lengths must stay in range)."""
    nodes = as_points(nodes, "nodes")
    if not np.all(np.isfinite(nodes)):
        raise ValueError("target nodes contain NaN or inf")
    top = np.abs(nodes).max(initial=0.0)
    if not top < tol.COORDINATE_MAX:
        raise ValueError(f"target coordinates reach {top:.3g}, beyond the supported "
                         f"{tol.COORDINATE_MAX:.0e}: rescale the mesh")
    return nodes


#: Columns of a block of facets: corners only (3, 4), or with mid-side nodes (higher order).
FACET_COLUMNS = (3, 4, 6, 7, 8, 9)


def as_faces(faces, n: int, columns=FACET_COLUMNS) -> list:
    """Facet blocks as a list of (f, k) int64 arrays, each k in `columns`, every entry a node
    index in [0, n); ValueError otherwise (a -1 would wrap to the last node, a float be cut).
    `faces`: None (no facets), one (f, k) array or list of rows, or a list of such blocks;
    empty blocks are kept as they are (no facets)."""
    if faces is None:
        return []
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        faces = [faces]  # one block of facets
    elif not isinstance(faces, np.ndarray) and len(faces) and np.ndim(faces[0]) == 1:
        faces = [faces]  # one block, as a list of rows
    blocks = []
    for f in faces:
        arr = np.asarray(f)
        if arr.size == 0:
            blocks.append(arr.astype(np.int64).reshape(0, arr.shape[-1] if arr.ndim == 2
                                                       else columns[0]))
            continue
        if arr.ndim != 2 or arr.shape[1] not in columns:
            counts = ", ".join(map(str, columns[:-1])) + f" or {columns[-1]}"
            raise ValueError(f"faces: a block of shape {arr.shape}, expected {counts} corners"
                             f"{' and mid-side nodes' if len(columns) > 2 else ''} per facet")
        if arr.dtype.kind not in "iu":
            if arr.dtype.kind != "f" or not np.all(np.isfinite(arr) & (arr == np.round(arr))):
                raise ValueError(f"faces: facet corners must be integers (node indices), got "
                                 f"{arr.dtype} values")
        if not (arr.dtype == np.int64 and arr.flags.c_contiguous and not arr.flags.writeable):
            arr = arr.astype(np.int64)  # a copy of the caller's: read-only int64 blocks are
            # a surface's own (PatchedSurface's, shared with its patch surfaces: issue 36)
        if arr.min() < 0 or arr.max() >= n:
            bad = arr.min() if arr.min() < 0 else arr.max()
            raise ValueError(f"faces: facet corners must index the {n} nodes (0 to {n - 1}), "
                             f"got {bad}")
        blocks.append(arr)
    return blocks


def bounds(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) the box of points x (n, 3), n >= 1: ``x.min(axis=0), x.max(axis=0)`` bit
    for bit, column by column (numpy's reduction over axis 0 of a (n, 3) array is several
    times slower). Which of -0.0 and 0.0 a tie keeps is the reduction's own: where a bound
    is zero, the reduction gives it."""
    x = np.asarray(x)
    lo = np.array([x[:, e].min() for e in range(x.shape[1])])
    hi = np.array([x[:, e].max() for e in range(x.shape[1])])
    if not (np.all(lo != 0) and np.all(hi != 0)):
        return x.min(axis=0), x.max(axis=0)
    return lo, hi


class InsideOutWarning(UserWarning):
    """A closed surface of the target's facets is wound inside out (`inside_out`): its
    normals point into the target, so every gap there has the wrong sign. ``facets``: the
    facets of such surfaces, ``total``: all the target's facets, ``volume``: what they
    enclose (< 0)."""

    def __init__(self, facets: int, total: int, volume: float, fix: str = "flip=True"):
        self.facets, self.total, self.volume = int(facets), int(total), float(volume)
        super().__init__(self.text(fix))

    def text(self, fix: str) -> str:
        """The message, naming `fix` (the API's keyword or the command line's flag)."""
        return (f"{self.facets} of the target's {self.total} facets are closed surfaces wound "
                f"inside out (enclosed volume {self.volume:.3g} < 0): their normals point into "
                f"the target and their gaps' signs are reversed; use {fix} (unless the target "
                f"is a cavity, its inside the void)")


def inside_out(nodes, faces, ident=None, edges=None) -> tuple[int, float]:
    """The closed surfaces of a target wound inside out: (facets, volume) of those of its
    connected surfaces that are closed and consistently wound (every edge run once each way
    by two facets; coincident nodes are one node) and enclose a negative volume (the
    divergence theorem: sum over facets of x0 . (x1 x x2) / 6), unless they lie within the box
    of a closed surface of positive volume (a cavity of a hollow body, a thin shell's inner
    wall, rightly wound into the void). Open surfaces have no inside and count for nothing.
    Linear in the facets (the edges' compiled pass, `patches.segment.edge_table`).

    nodes : (n, 3) float; faces : facet blocks as `as_faces` returns them; ident : (n,) int,
    optional: the first node at each node's position (computed when not given); edges :
    optional, the facet edges (`patches.segment.edge_table` of `faces` by `ident`) where the
    caller has them (`PatchedSurface`), computed when not given."""
    from .facet import _setup
    from .patches import segment as _segment

    blocks = [np.asarray(f)[:, :4 if f.shape[1] in (4, 8, 9) else 3] for f in faces if len(f)]
    if not blocks:
        return 0, 0.0
    F = sum(len(f) for f in blocks)
    if edges is None:
        if ident is None:
            ident = _segment.node_identity(nodes)
        edges = _segment.edge_table(blocks, np.asarray(ident).ravel())
    # an edge of two facets running it opposite ways (one half-edge from its smaller node
    # identity to its larger) joins them; any other edge (open, non-manifold, or run the same
    # way twice) leaves its facets' surface unclosed: one compiled pass over the edges
    # (`_edges.closed_pairs`), the pairs in edge order and the facets of the other edges
    from .patches import _edges

    i64 = _segment._i64
    a, b, open_facet = _edges.closed_pairs(
        i64(edges.start), i64(edges.order), i64(edges.fac),
        np.ascontiguousarray(edges.forward, dtype=np.int8), F)
    comp = _segment.components(F, a, b)
    del a, b
    open_comp = np.zeros(comp.max() + 1, bool)
    open_comp[comp[open_facet.view(bool)]] = True
    del open_facet
    # enclosed volume per surface, about the centre of the nodes (round-off of far meshes):
    # six times each facet's, one compiled pass a block (x0 . (x1 x x2), plus x0 . (x2 x x3)
    # for a quad, as numpy's einsum of np.cross summed them: the same volumes bit for bit)
    x = np.asarray(nodes, dtype=np.float64)
    lo, hi = bounds(x)
    x = np.ascontiguousarray(x - 0.5 * (lo + hi))
    vol = np.concatenate([_setup.facet_volumes(x, np.asarray(f, dtype=np.int64))
                          for f in blocks])
    volume = np.bincount(comp, weights=vol / 6.0)
    del vol
    bad = ~open_comp & (volume < 0)
    outer = np.flatnonzero(~open_comp & (volume > 0))
    if bad.any() and len(outer):  # a cavity: inside the box of a body wound outward
        corners = np.concatenate([np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1)
                                  for f in blocks])
        ncomp = len(volume)
        lo = np.full((ncomp, 3), np.inf)
        hi = np.full((ncomp, 3), -np.inf)
        at = np.repeat(comp, 4)[corners.ravel() >= 0]
        pts = x[corners.ravel()[corners.ravel() >= 0]]
        np.minimum.at(lo, at, pts)
        np.maximum.at(hi, at, pts)
        for c in np.flatnonzero(bad):
            if np.any(np.all(lo[outer] <= lo[c], axis=1) & np.all(hi[outer] >= hi[c], axis=1)):
                bad[c] = False
    return int(bad[comp].sum()), float(volume[bad].sum())


def warn_inside_out(nodes, faces, ident=None, stacklevel: int = 3, *, edges=None) -> None:
    """`warnings.warn` an `InsideOutWarning` naming flip=True where the target's facets hold
    a closed surface wound inside out (`inside_out`; `edges`: its facet edges, if known)."""
    import warnings

    facets, volume = inside_out(nodes, faces, ident, edges)
    if facets:
        warnings.warn(InsideOutWarning(facets, sum(len(f) for f in faces), volume),
                      stacklevel=stacklevel)


def as_moved_nodes(nodes, current: np.ndarray) -> np.ndarray:
    """New positions of a target's `current` nodes (a surface's `moved`): `as_target_nodes`,
    refused (ValueError) unless there is one per node."""
    nodes = as_target_nodes(nodes)
    if nodes.shape != current.shape:
        raise ValueError(f"moved: expected the target's {len(current)} nodes, got an array "
                         f"of shape {nodes.shape}")
    return nodes


@runtime_checkable
class Surface(Protocol):
    """What every target surface is to its callers (`DiffuseSurface`, `FacetSurface`,
    `PatchedSurface`): geometric answers, which the command line uses and nothing else. A
    surface builds no contact element: `element.contact` and `assemble` choose the element by
    the surface's type and build it from the surface's answers.

    Attributes
    ----------
    nodes : (n, 3) float
        The target's nodes; element node indices (`Contact.nodes`) index them.
    node_spacing : (n,) float
        The local node spacing h of each node (tolerances are relative to it).

    Methods
    -------
    facet_surface() -> FacetSurface or None
        The target's own facets (a FacetSurface: itself); None for a cloud of nodes.
    project(points, *, keep_patch=False, progress=None) -> Projection
        Each contactor's gap [32], normal [29], proximal point [25], status [33] and reason
        (with ``keep_patch``, the pairing in ``.patch``: the diffuse surfaces').
    project_with(points, pairing) -> Projection
        The same with a frozen pairing (a `Patch`; the facets' facet indices).
    """

    nodes: np.ndarray
    node_spacing: np.ndarray

    def facet_surface(self):
        ...

    def project(self, points, *, keep_patch: bool = False, progress=None) -> Projection:
        ...

    def project_with(self, points, pairing) -> Projection:
        ...
