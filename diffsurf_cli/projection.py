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
    """

    source: np.ndarray
    patch: Patch | None = None
    facet: np.ndarray | None = None

    def take(self, rows) -> Pairing:
        """The pairing of contactors `rows` (indices or a slice)."""
        return Pairing(np.asarray(self.source)[rows],
                       None if self.patch is None else self.patch.take(rows),
                       None if self.facet is None else np.asarray(self.facet)[rows])


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
        """The output columns x,y,z,gap,nx,ny,nz,px,py,pz,status,support,iterations,rcond,
        reason, and terms when known."""
        p, n, d = self.points, self.normal, self.proximal_point
        return {
            "x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "gap": self.gap,
            "nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2],
            "px": d[:, 0], "py": d[:, 1], "pz": d[:, 2],
            "status": self.status, "support": self.support, "iterations": self.iterations,
            "rcond": self.rcond, "reason": self.reason,
            **({} if self.terms is None else {"terms": self.terms}),
        }


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
    `PatchedSurface`): `element.contact`, `assemble` and the command line use nothing else.

    Attributes
    ----------
    nodes : (n, 3) float
        The target's nodes; element node indices (`Contact.nodes`) index them.

    Methods
    -------
    project(points, *, keep_patch=False, progress=None) -> Projection
        Each contactor's gap [32], normal [29], proximal point [25], status [33] and reason
        (with ``keep_patch``, the pairing in ``.patch``: the diffuse surfaces').
    project_with(points, pairing) -> Projection
        The same with a frozen pairing (a `Patch`; the facets' facet indices).
    contact(points, *, rigid_target=False, pairing=None, second=True) -> element.Contact
        The contact element of every closed contact (g < 0): g, 𝒩, ℳ [§2, §4.2-4.3].
    """

    nodes: np.ndarray

    def project(self, points, *, keep_patch: bool = False, progress=None) -> Projection:
        ...

    def project_with(self, points, pairing) -> Projection:
        ...

    def contact(self, points, *, rigid_target: bool = False, pairing=None, second: bool = True):
        ...
