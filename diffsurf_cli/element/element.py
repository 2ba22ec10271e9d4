"""The contact element: gap, 𝒩 = ∂g/∂u and ℳ = ∂²g/∂u², residual and tangent [§4.2-4.3], [§2].

Unknowns of one element are u = [x^c, x^1, ..., x^n] [22] (3(n+1) numbers): the contactor and
the nodes its gap depends on (the support of its local approximation for the diffuse element,
the facet's nodes for node-to-facet). With the penalty method [3], the residual and tangent are
R = ε g 𝒩 [45] and K = ε (g ℳ + 𝒩 𝒩ᵀ) [54], the gradient and Hessian of ε g²/2.

Both elements are written once, generically: a surface point x(X, u) with in-plane parameters X
and unit normal ν(X, u); the proximal point X̄(u) is stationary for D = ½‖x^c - x‖² ([30], or
the facet's closest point [1]); the gap is G(X̄, u) with G = (x^c - x)·ν [32]. Then, because
∂G/∂X = 0 at X̄ (x^c - x^d is parallel to ν and ⊥ τ_k),

    𝒩 = ∂G/∂u                                   (the paper's [42]-[44]: no ∂X̄ needed)
    ℳ = ∂²G/∂u² + ∂²G/∂u∂X · ∂X̄/∂u,  ∂X̄/∂u = -(∂²D/∂X²)⁻¹ ∂²D/∂X∂u   (implicit function theorem)

which gathers the paper's 𝒮_l, 𝒯_l, 𝒰 and 𝒟_τ terms [48]-[53]. The diffuse element is
computed by the compiled engine (`diffuse.diffuse_elements`), the node-to-facet one by
`facet.facet_element`, both with analytic derivatives; their jet-based (forward-mode automatic
differentiation) oracles are in tests/oracle_element.py. The frame, the support set and the
radius R are held fixed, as in the paper.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .diffuse import diffuse_elements
from .facet import facet_element


@dataclass
class Element:
    """One contact element.

    contactor : int          index of the contactor x^c
    nodes : (n,) int         target node indices in u = [x^c, x^nodes[0], ...] order
    gap : float              g [32]
    N : (3(n+1),) float      ∂g/∂u (the paper's 𝒩 [42])
    M : (3(n+1), 3(n+1)) float or None   ∂²g/∂u² (the paper's ℳ [53]), when asked for
    """

    contactor: int
    nodes: np.ndarray
    gap: float
    N: np.ndarray
    M: np.ndarray | None

    def residual(self, penalty: float) -> np.ndarray:
        """R = ε g 𝒩 [45]."""
        return penalty * self.gap * self.N

    def tangent(self, penalty: float) -> np.ndarray:
        """K = ε (g ℳ + 𝒩 𝒩ᵀ) [54]."""
        return penalty * (self.gap * self.M + np.outer(self.N, self.N))


def diffuse_element(surface, contactor: np.ndarray, index: np.ndarray, origin: np.ndarray,
                    axes: np.ndarray, radius: float, proximal_point: np.ndarray,
                    second: bool = True, reduced: int = -1, direction: float = np.nan):
    """Gap, 𝒩 and ℳ of the diffuse element of one contactor [§4] (`diffuse_elements` of one row).

    Parameters
    ----------
    surface : DiffuseSurface
        Provides the target nodes, the basis and the weight.
    contactor : (3,) float
    index : (K,) int
        Support node indices (-1 padding allowed); only nodes with positive weight enter u.
    origin : (3,) float
    axes : (3, 3) float
    radius : float
        The frozen pairing (frame R^d and R).
    proximal_point : (3,) float
        x^d from the projection (it fixes the stationary X̄).
    second : bool
        Compute ℳ too (the tangent needs it; the residual does not).
    reduced, direction : int, float
        The reduced basis the projection fitted (an index into basis.REDUCED, -1 the full
        basis) and the angle of its a axis from e1 (`Patch.reduced`, `Patch.direction`: a
        strip's support), held fixed as the frame is.

    Returns
    -------
    gap : float
    nodes : (n,) int   the support nodes in u's order
    N : (3(n+1),) float
    M : (3(n+1), 3(n+1)) float or None
    """
    from ..mls.surface import Patch

    patch = Patch(np.reshape(origin, (1, 3)), np.reshape(axes, (1, 3, 3)),
                  np.reshape(float(radius), (1,)), np.full(1, np.nan), np.reshape(index, (1, -1)),
                  np.full(1, int(reduced), dtype=np.int8), np.full(1, float(direction)))
    gap, nodes, N, M = diffuse_elements(surface, np.reshape(contactor, (1, 3)), patch,
                                        np.reshape(proximal_point, (1, 3)), [0], second)
    return float(gap[0]), nodes[0], N[0], (M[0] if second else None)


@dataclass
class Contact:
    """Contact elements of a scene and their assembly.

    projection : Projection     gaps, normals, statuses of every contactor
    elements : list of Element  one per closed contact (g < 0), in contactor order
    """

    projection: object
    elements: list

    def residual(self, penalty: float, n_contactors: int, target_dof_node: np.ndarray,
                 n_target_points: int) -> np.ndarray:
        """Assembled global residual Σ ε g 𝒩 [45] over the closed contacts."""
        out = np.zeros(3 * (n_contactors + n_target_points))
        for e in self.elements:
            np.add.at(out, _dofs(e, n_contactors, target_dof_node), e.residual(penalty))
        return out

    def tangent(self, penalty: float, n_contactors: int, target_dof_node: np.ndarray,
                n_target_points: int) -> sp.csr_matrix:
        """Assembled global tangent Σ ε (g ℳ + 𝒩 𝒩ᵀ) [54], sparse and symmetric."""
        rows, cols, vals = [], [], []
        for e in self.elements:
            dofs = _dofs(e, n_contactors, target_dof_node)
            rows.append(np.repeat(dofs, len(dofs)))
            cols.append(np.tile(dofs, len(dofs)))
            vals.append(e.tangent(penalty).ravel())
        size = 3 * (n_contactors + n_target_points)
        if not rows:
            return sp.csr_matrix((size, size))
        return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(size, size)).tocsr()

    def energy(self, penalty: float) -> float:
        """Σ ε g²/2 over the closed contacts: R and K are its gradient and Hessian."""
        return float(sum(0.5 * penalty * e.gap**2 for e in self.elements))


def _dofs(e: Element, n_contactors: int, target_dof_node: np.ndarray) -> np.ndarray:
    """Global DOFs of an element: dof = 3 node + component; contactors first, then target."""
    nodes = np.concatenate([[e.contactor], n_contactors + target_dof_node[e.nodes]])
    return (3 * nodes[:, None] + np.arange(3)).ravel()


def contact(surface, points, *, second: bool = True, pairing=None) -> Contact:
    """Project `points` and build the contact element of every closed contact (g < 0).

    Parameters
    ----------
    surface : DiffuseSurface or FacetSurface
    points : (m, 3) float
    second : bool
        Build ℳ (for the tangent); the residual needs only 𝒩.
    pairing : Patch, optional
        A frozen pairing (diffuse method) to reuse instead of searching again.

    Returns
    -------
    Contact
    """
    from ..facet.surface import FacetSurface
    from ..mls.surface import PENETRATION

    points = np.asarray(points, dtype=np.float64)
    if isinstance(surface, FacetSurface):
        proj = surface.project(points) if pairing is None else surface.project_with(points, pairing)
    else:
        if surface.recentre:
            raise ValueError("the contact element is defined on the contactor's own local "
                             "approximation: use it without re-centring")
        proj = (surface.project(points, keep_patch=True) if pairing is None
                else surface.project_with(points, pairing))
    elements = []
    for i in np.flatnonzero(proj.status == PENETRATION):
        if isinstance(surface, FacetSurface):
            corners = surface.facets[proj.facet[i]]
            corners = corners[corners >= 0]
            d = points[i] - proj.proximal_point[i]
            side = 1.0 if np.dot(d, proj.normal[i]) >= 0 else -1.0
            g, N, M = facet_element(surface.nodes[corners], points[i], proj.param[i],
                                    side, surface.sign, second)
            nodes = corners
        else:
            p = proj.patch
            g, nodes, N, M = diffuse_element(
                surface, points[i], p.index[i], p.origin[i], p.axes[i], p.radius[i],
                proj.proximal_point[i], second,
                -1 if p.reduced is None else int(p.reduced[i]),
                np.nan if p.direction is None else float(p.direction[i]))
        elements.append(Element(int(i), np.asarray(nodes), g, N, M))
    return Contact(proj, elements)
