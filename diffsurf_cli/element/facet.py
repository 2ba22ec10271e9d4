"""The node-to-facet contact element [§2]: gap, 𝒩 = ∂g/∂u [7] and ℳ = ∂²g/∂u² [9]-[10].

Unknowns u = [x^c, x^1, ..., x^p] [5] (p = 3 for a linear triangle, 4 for a bilinear quad).
The closest point x^m = Σ_j N_j(ξ) x_j [1] has facet parameters ξ = ξ0 + E θ: θ the free
ones (two inside the facet, one on an edge, none at a vertex). With d = x^c - x^m:

- inside, g = sign d·m/|m|, m = t_a × t_b the facet's normal vector, t_α = Σ_j N_j,α x_j [2];
- on an edge or at a vertex, g = side |d| (the signed distance to that point).

θ is stationary for D = ½ d·d, so 𝒩 = ∂g/∂u at fixed θ and
ℳ = ∂²g/∂u² - ∂²g/∂u∂θ (∂²D/∂θ²)⁻¹ ∂²D/∂θ∂u (implicit function theorem), written out in
closed form in the compiled engine (`_element.facet_elements`, its comment gives the terms),
in parallel over contactors. Its oracle is the jet (forward-mode automatic differentiation)
element of tests/oracle_element.py.
"""
from __future__ import annotations

import numpy as np

from . import _element

#: Width of a node-to-facet element's 𝒩 (u = [x^c, 4 corners]; a triangle's 4th is padding).
WIDTH = 15


def facet_elements(nodes, corners, contactors, xi, side, sign=1.0, second=True):
    """Gap, 𝒩 and ℳ of the node-to-facet element of each contactor (the compiled engine).

    Parameters
    ----------
    nodes : (n, 3) float
    corners : (e, 4) int
        Each element's facet corners, -1 in the 4th column for a triangle.
    contactors : (e, 3) float
    xi : (e, 2) float
        Facet parameters of each closest point x^m [1].
    side : (e,) float
        +1 or -1: the side of the facet each contactor is on (used at edges and vertices,
        where the gap is the signed distance to x^m).
    sign : float
        -1 to reverse the facet orientation.
    second : bool
        Compute ℳ too.

    Returns
    -------
    gap (e,), N (e, 15), M (e, 15, 15) or None, u = [x^c, x^corners...] (zero on a
    triangle's padding; NaN rows: a degenerate facet).
    """
    e = len(contactors)
    gap = np.empty(e)
    N = np.zeros((e, WIDTH))
    M = np.zeros((e, WIDTH, WIDTH)) if second else np.zeros((0, 0, 0))
    _element.facet_elements(np.ascontiguousarray(nodes, dtype=np.float64),
                            np.ascontiguousarray(corners, dtype=np.int64).reshape(e, 4),
                            np.ascontiguousarray(contactors, dtype=np.float64).reshape(e, 3),
                            np.ascontiguousarray(xi, dtype=np.float64).reshape(e, 2),
                            np.ascontiguousarray(side, dtype=np.float64).reshape(e),
                            float(sign), gap, N, M)
    return gap, N, (M if second else None)


def facet_element(corners: np.ndarray, contactor: np.ndarray, xi: np.ndarray, side: float,
                  sign: float = 1.0, second: bool = True):
    """Gap, 𝒩 and ℳ of one node-to-facet element [§2], [7]-[10] (`facet_elements`).

    corners : (3, 3) or (4, 3) float, the facet's nodes; contactor (3,); xi (2,) the closest
    point's facet parameters; side ±1; sign -1 to reverse the facet orientation.

    Returns gap, N (3(p+1),), M (3(p+1), 3(p+1)) or None, with u = [x^c, x^1..x^p] [5].
    """
    corners = np.asarray(corners, dtype=np.float64)
    p = len(corners)
    index = np.array([[0, 1, 2, 3 if p == 4 else -1]], np.int64)
    gap, N, M = facet_elements(corners, index, np.asarray(contactor)[None],
                               np.asarray(xi)[None], [float(side)], sign, second)
    n = 3 * (p + 1)
    return float(gap[0]), N[0, :n], (M[0, :n, :n] if second else None)
