"""The contact patch test (Taylor & Papadopoulos 1991; El-Abbasi & Bathe 2001), with scikit-fem:
two elastic blocks on [0, 1]², one on the other, a uniform pressure p on top, the interface
flat and its meshes matching or not. The exact answer is uniform: σ_zz = -p in both blocks,
and the contact forces at the interface are the consistent nodal forces of p on each face
(p times each node's tributary area). How FE engineers judge a contact discretisation: a
method that passes transfers a uniform pressure exactly across non-matching meshes.

The model: hexahedra (`skfem.ElementHex1`), linear elasticity, small strain, E = 1,
ν = 0.3; the lower block z in [0, H], the upper in [H, 2H], `LAYERS` layers each; rollers
(u_x = 0 on x = 0, u_y = 0 on y = 0, both blocks; u_z = 0 under the lower block) leave the
uniform solution free to expand sideways; p loads the upper block's top face (its consistent
nodal forces). Contact by the penalty [3]: ε_i = `penalty` x the contactor's tributary area,
Newton on the contact's exact tangent until the residual falls below 1e-12 of the load.

A pass: the contactors are one block's interface nodes, the target the other block's
interface face (its quads wound out of their body), built as `surface` ("diffuse": a bare
`DiffuseSurface` with its defaults; "facets": `FacetSurface`, node-to-facet) and `moved`
with its body at every iteration. "upper": the upper block's nodes on the lower block's
face; "lower": the other way; "two": both passes, each with half the penalty.

Measured (`PatchResult`): the largest |σ_zz + p| / p over the elements of both interface
layers (at their centroids), and the largest deviation of each body's interface nodal
forces (contact forces, contactor or target side) from the consistent ones, relative to the
largest consistent force.

    python benchmarks/patch_test.py     # the table, diffuse against node-to-facet
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

E, NU = 1.0, 0.3
H = 0.6              # each block's height
LAYERS = 3
PRESSURE = 1e-4
#: The penalty per unit area: p / ε is the penetration, about 1e-7 of a 1/5 element.
PENALTY = PRESSURE / (1e-7 * 0.2)


@dataclass
class Block:
    mesh: object          # skfem.MeshHex
    basis: object         # vector Hex1 basis
    K: sp.csr_matrix
    X: np.ndarray         # (n, 3) reference nodes
    dofs: np.ndarray      # (n, 3) global DOFs
    face: np.ndarray      # its interface nodes (z = H)
    quads: np.ndarray     # its interface quads, node ids (into X), wound out of the body
    area: np.ndarray      # tributary area of each interface node (face order)


@dataclass
class PatchResult:
    stress: float         # max |σ_zz + p| / p over both interface layers
    force_upper: float    # max deviation of the upper face's nodal forces (relative)
    force_lower: float    # ... of the lower face's
    iterations: int
    converged: bool
    unanswered: int       # interface contactors penetrating without an element (last iterate)
    residuals: list       # Newton's |r| / |f| per iteration

    @property
    def force(self) -> float:
        return max(self.force_upper, self.force_lower)


def _grid_block(n, z0: float, first_dof: int, top: bool, shift=(0.0, 0.0),
                tetra: bool = False) -> Block:
    """A block [0, 1]² x [z0, z0 + H] of n = (nx, ny) cells in plane, LAYERS in z; its
    interface face is its top (`top`) or bottom, quads wound out of the block
    (`targets.outward_faces`). `shift`
    moves the inner grid lines (an offset, non-uniform grid) without moving the boundary."""
    import skfem
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    from diffsurf_cli.targets import outward_faces

    def axis(k, s):
        t = np.linspace(0.0, 1.0, k + 1)
        t[1:-1] += s / k
        return t

    kind, element = ((skfem.MeshTet, skfem.ElementTetP1()) if tetra
                     else (skfem.MeshHex, skfem.ElementHex1()))
    mesh = kind.init_tensor(axis(n[0], shift[0]), axis(n[1], shift[1]),
                            np.linspace(z0, z0 + H, LAYERS + 1))
    basis = skfem.Basis(mesh, skfem.ElementVector(element))
    K = skfem.asm(linear_elasticity(*lame_parameters(E, NU)), basis).tocsr()
    X = mesh.p.T.copy()
    z = z0 + H if top else z0
    face = np.flatnonzero(np.isclose(X[:, 2], z))
    face = face[np.lexsort((X[face, 0], X[face, 1]))]
    # the interface quads: the body's boundary facets there, wound out of the body
    facets = mesh.facets[:, mesh.boundary_facets()].T
    quads = outward_faces(X, facets[np.isclose(X[facets, 2], z).all(axis=1)], mesh.t.T)
    area = np.zeros(len(X))
    k = quads.shape[1]
    for f in range(k):  # a face's area, shared equally by its corners (its consistent load)
        np.add.at(area, quads[:, f], _areas(X[quads]) / k)
    return Block(mesh, basis, K, X, basis.nodal_dofs.T.copy() + first_dof, face, quads,
                 area[face])


def _areas(P: np.ndarray) -> np.ndarray:
    """Areas of flat triangles (f, 3, 3) or quads (f, 4, 3)."""
    if P.shape[1] == 3:
        return np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1) / 2
    return np.linalg.norm(np.cross(P[:, 2] - P[:, 0], P[:, 3] - P[:, 1]), axis=1) / 2


@dataclass
class Model:
    lower: Block
    upper: Block
    K: sp.csr_matrix
    f: np.ndarray         # the external load
    free: np.ndarray
    n_dofs: int


def build(lower=(5, 5), upper=(4, 4), shift_lower=(0.0, 0.0),
          shift_upper=(0.0, 0.0), tetra: bool = False) -> Model:
    """Both blocks (hexahedra, or with `tetra` tetrahedra: scikit-fem's split of each hex),
    their stiffness, the load and the rollers."""
    lo = _grid_block(lower, 0.0, 0, True, shift_lower, tetra)
    up = _grid_block(upper, H, 3 * len(lo.X), False, shift_upper, tetra)
    n_dofs = 3 * (len(lo.X) + len(up.X))
    K = sp.block_diag([lo.K, up.K]).tocsr()
    f = np.zeros(n_dofs)
    facets = up.mesh.facets[:, up.mesh.boundary_facets()].T
    top = facets[np.isclose(up.X[facets, 2], 2 * H).all(axis=1)]
    for k in range(top.shape[1]):  # p's consistent nodal forces on the top face
        np.add.at(f, up.dofs[top[:, k], 2], -PRESSURE * _areas(up.X[top]) / top.shape[1])
    fixed = []
    for b in (lo, up):
        fixed.append(b.dofs[np.isclose(b.X[:, 0], 0.0), 0])
        fixed.append(b.dofs[np.isclose(b.X[:, 1], 0.0), 1])
    fixed.append(lo.dofs[np.isclose(lo.X[:, 2], 0.0), 2])
    free = np.setdiff1d(np.arange(n_dofs), np.concatenate(fixed))
    return Model(lo, up, K, f, free, n_dofs)


def _surface(kind: str, nodes, quads, old=None):
    from diffsurf_cli import DiffuseSurface, FacetSurface

    if old is not None:
        return old.moved(nodes)
    if kind == "diffuse":
        return DiffuseSurface(nodes, [quads])
    if kind.startswith("diffuse:"):  # options: "diffuse:weight=singular,basis=linear"
        options = {k: _value(v) for k, v in (item.split("=", 1)
                                             for item in kind.split(":", 1)[1].split(","))}
        return DiffuseSurface(nodes, [quads], **options)
    if kind == "facets":
        return FacetSurface(nodes, [quads])
    if kind == "default":  # what `diffsurf project` builds: patches, flat faces, the guard
        from diffsurf_cli.targets import build_surface

        return build_surface(nodes, [quads])
    raise ValueError(f"surface: 'diffuse' or 'facets', not {kind!r}")


def _value(text: str):
    """An option's value: a number where it reads as one."""
    try:
        return float(text)
    except ValueError:
        return text


def _passes(model: Model, way: str):
    """(contactor block, target block, weight) of each pass."""
    ways = {"upper": [(model.upper, model.lower, 1.0)],
            "lower": [(model.lower, model.upper, 1.0)],
            "two": [(model.upper, model.lower, 0.5), (model.lower, model.upper, 0.5)]}
    if way not in ways:
        raise ValueError(f"pass: 'upper', 'lower' or 'two', not {way!r}")
    return ways[way]


def contact_terms(model: Model, u: np.ndarray, way: str, kind: str, penalty: float,
                  surfaces: dict, gauss: int = 0, transfer: bool = False,
                  tied: bool = False):
    """R and K of every pass at displacement u; the number of interface contactors that
    penetrate the facets but have no element. With `gauss` = n > 0 the contactors are the
    n x n Gauss points of the contactor face's facets (`gauss_points`), not its nodes: each
    point's element acts on its facet's nodes through their shape functions at it. `tied`
    (with `transfer` only): every contactor within a unit of the target has an element and
    the force ε g of either sign, open ones too (a study of the active set's part)."""
    from diffsurf_cli import contact

    R = np.zeros(model.n_dofs)
    K = sp.csr_matrix((model.n_dofs, model.n_dofs))
    unanswered = 0
    for c_blk, t_blk, weight in _passes(model, way):
        nodes = t_blk.X + u[t_blk.dofs]
        key = id(t_blk)
        surfaces[key] = _surface(kind, nodes[t_blk.face], _local(t_blk), surfaces.get(key))
        td = t_blk.dofs[t_blk.face]
        if gauss:
            shape, area = gauss_points(c_blk, gauss)  # (q, n_face) sparse, (q,)
            x = shape @ (c_blk.X[c_blk.face] + u[c_blk.dofs[c_blk.face]])
            # the points' own DOFs past the model's, mapped onto the face nodes' by T
            cd = model.n_dofs + np.arange(3 * len(x)).reshape(-1, 3)
            T = sp.vstack([sp.identity(model.n_dofs, format="csr"),
                           sp.kron(shape, sp.identity(3)) @ _selector(c_blk, model.n_dofs)])
            n_ext = model.n_dofs + 3 * len(x)
        else:
            area, x = c_blk.area, c_blk.X[c_blk.face] + u[c_blk.dofs[c_blk.face]]
            cd, T, n_ext = c_blk.dofs[c_blk.face], None, model.n_dofs
        if tied and not transfer:
            raise ValueError("tied: with transfer=True only")
        c = contact(surfaces[key], x, near=1.0 if tied else 0.0)
        eps = weight * penalty * area
        if transfer:
            Rp, Kp = _through_facets(c, surfaces[key], x, eps, cd, td, n_ext, tied)
        else:
            Rp, Kp = c.residual(eps, cd, td, n_ext), c.tangent(eps, cd, td, n_ext)
        if T is not None:
            Rp, Kp = T.T @ Rp, (T.T @ Kp @ T).tocsr()
        R += Rp
        K = K + Kp
        facets = _surface("facets", nodes[t_blk.face], _local(t_blk)).project(x)
        has = np.zeros(len(x), bool)
        has[c.contactor] = True
        unanswered += int(np.sum((facets.gap < 0) & ~has))
    return R, K, unanswered


def _through_facets(c, surface, x, eps, cd, td, n_dofs, tied=False):
    """R and K of the diffuse elements of `c` with their force passed to the target
    through its facets (`element.transfer`); `tied`: the force ε g of either sign."""
    from diffsurf_cli.testing.facet_transfer import facet_transfer

    facets = surface.facet_surface()
    facet = facets.project(c.projection.proximal_point[c.contactor]).facet
    corners = np.full((len(facets.facets), 4), -1)
    corners[:, :facets.facets.shape[1]] = facets.facets
    kind = (corners >= 0).sum(axis=1)
    unknowns, W, Nu, dW = facet_transfer(surface.nodes, corners, kind, x[c.contactor],
                                         c.nodes, c.N, np.asarray(c.M), facet)
    eps = np.broadcast_to(eps, (len(x),))[c.contactor]
    p = eps * c.gap if tied else np.minimum(eps * c.gap, 0.0)
    active = (p < 0) | (c.gap <= 0) | tied
    dofs = np.concatenate([cd[c.contactor][:, None, :],
                           np.where(unknowns[..., None] >= 0, td[np.maximum(unknowns, 0)], -1)],
                          axis=1).reshape(len(p), -1)
    R = np.zeros(n_dofs)
    Ke = (np.where(active, eps, 0.0)[:, None, None] * W[:, :, None] * Nu[:, None, :]
          + p[:, None, None] * dW)
    ok = dofs >= 0
    np.add.at(R, dofs[ok], (p[:, None] * W)[ok])
    rows = np.broadcast_to(dofs[:, :, None], Ke.shape)
    cols = np.broadcast_to(dofs[:, None, :], Ke.shape)
    keep = (rows >= 0) & (cols >= 0)
    K = sp.csr_matrix((Ke[keep], (rows[keep], cols[keep])), shape=(n_dofs, n_dofs))
    return R, K


def gauss_points(b: Block, n: int):
    """The n x n Gauss points of block b's interface facets (quads: the tensor rule;
    triangles: the collapsed one): (q, len(b.face)) sparse shape functions of the face nodes
    at each point, and (q,) each point's area weight (in the reference configuration)."""
    t, w = np.polynomial.legendre.leggauss(n)
    t, w = (t + 1) / 2, w / 2
    a, bb = (arr.ravel() for arr in np.meshgrid(t, t, indexing="ij"))
    wq = np.outer(w, w).ravel()
    local = _local(b)
    k = local.shape[1]
    if k == 4:
        N = np.stack([(1 - a) * (1 - bb), a * (1 - bb), a * bb, (1 - a) * bb], 1)
        dN = np.stack([np.stack([-(1 - bb), 1 - bb, bb, -bb], 1),
                       np.stack([-(1 - a), -a, a, 1 - a], 1)], 0)
    else:  # the square onto the triangle: ξ = a, η = b (1 - a), dA = (1 - a) da db
        xi, eta = a, bb * (1 - a)
        N = np.stack([1 - xi - eta, xi, eta], 1)
        wq = wq * (1 - a)
        dN = np.broadcast_to(np.array([[[-1.0, 1.0, 0.0]], [[-1.0, 0.0, 1.0]]]),
                             (2, len(a), 3))
    P = b.X[b.face][local]                                     # (f, k, 3)
    J = np.einsum("dqk,fkc->fqdc", dN, P)                      # (f, q, 2, 3)
    area = np.linalg.norm(np.cross(J[:, :, 0], J[:, :, 1]), axis=2) * wq[None]
    rows = np.repeat(np.arange(local.shape[0] * len(a)), k)
    cols = np.repeat(local, len(a), axis=0).ravel()
    vals = np.tile(N, (local.shape[0], 1)).ravel()
    shape = sp.csr_matrix((vals, (rows, cols)), shape=(len(rows) // k, len(b.face)))
    return shape, area.ravel()


def _selector(b: Block, n_dofs: int) -> sp.csr_matrix:
    """(3 len(face), n_dofs): the face nodes' DOFs, node-major, out of the model's."""
    d = b.dofs[b.face].ravel()
    return sp.csr_matrix((np.ones(len(d)), (np.arange(len(d)), d)), shape=(len(d), n_dofs))


def _local(b: Block) -> np.ndarray:
    """The interface quads in face-node numbering."""
    index = np.full(len(b.X), -1)
    index[b.face] = np.arange(len(b.face))
    return index[b.quads]


def solve(model: Model, way: str = "upper", kind: str = "diffuse",
          penalty: float = PENALTY, max_iter: int = 30, tol: float = 1e-12,
          start: float | None = None, gauss: int = 0, transfer: bool = False,
          tied: bool = False) -> PatchResult:
    """Newton on the whole load from a flat start (both faces at z = H); the patch test's
    deviations at the converged state."""
    u = np.zeros(model.n_dofs)
    if start is not None:  # an initial guess: the upper block lowered by `start`
        u[model.upper.dofs[:, 2]] = -start
    surfaces: dict = {}
    load = np.linalg.norm(model.f)
    converged, its, unanswered = False, 0, 0
    history = []
    for its in range(max_iter + 1):
        Rc, Kc, unanswered = contact_terms(model, u, way, kind, penalty, surfaces, gauss,
                                           transfer, tied)
        r = model.K @ u + Rc - model.f
        history.append(float(np.linalg.norm(r[model.free]) / load))
        if history[-1] <= tol:
            converged = True
            break
        if its == max_iter:
            break
        A = (model.K + Kc)[model.free][:, model.free].tocsc()
        u[model.free] -= spla.spsolve(A, r[model.free])
    return PatchResult(_stress(model, u), *_forces(model, u, Rc), its, converged, unanswered,
                       history)


def _stress(model: Model, u: np.ndarray) -> float:
    """max |σ_zz + p| / p at the centroids of both interface layers' elements."""
    from skfem.helpers import sym_grad
    from skfem.models.elasticity import lame_parameters

    lam, mu = lame_parameters(E, NU)
    worst = 0.0
    for b, z in ((model.lower, H - H / LAYERS / 2), (model.upper, H + H / LAYERS / 2)):
        # the elements of the layer next to the interface: centroids within half a layer of
        # its middle
        w = b.basis.interpolate(u[_ordered(b)])
        eps = sym_grad(w)
        szz = lam * (eps[0, 0] + eps[1, 1] + eps[2, 2]) + 2 * mu * eps[2, 2]
        centre = b.mesh.p[:, b.mesh.t].mean(axis=1)[2]
        layer = np.abs(centre - z) < H / LAYERS / 2
        worst = max(worst, float(np.abs(szz.mean(axis=1)[layer] + PRESSURE).max()))
    return worst / PRESSURE


def _ordered(b: Block) -> np.ndarray:
    """The global DOFs of block b in its basis's own DOF order."""
    order = np.empty(b.basis.N, np.int64)
    order[b.basis.nodal_dofs.T.ravel()] = b.dofs.ravel()
    return order


def _forces(model: Model, u: np.ndarray, Rc: np.ndarray):
    """Each interface's nodal contact forces against the consistent ones: the upper face
    is pushed up by p, the lower one down."""
    out = []
    for b, sign in ((model.upper, 1.0), (model.lower, -1.0)):
        fz = -Rc[b.dofs[b.face, 2]]
        exact = sign * PRESSURE * b.area
        out.append(float(np.abs(fz - exact).max() / np.abs(exact).max()))
    return out


def common_bend(model: Model, kind: str, q, s: float = 1e-3) -> float:
    """Both interface faces bent together by s q(X) (z += s q at every node of both, q a
    function of the (n, 3) reference nodes): the largest |gap| / s over both passes, each
    body's nodes on the other's face built as `kind` (`solve`'s kinds). The facets answer
    each face's own interpolation error, about s h² q''/8; a surface that reproduces q from
    either face's nodes (a quadratic basis: every quadratic q) answers 0 to round-off, so the
    two passes together put no force against that bend."""
    bent = {}
    for b in (model.upper, model.lower):
        P = b.X[b.face].copy()
        P[:, 2] += s * q(b.X[b.face])
        bent[id(b)] = P
    worst = 0.0
    for c_blk, t_blk, _ in _passes(model, "two"):
        gap = _surface(kind, bent[id(t_blk)], _local(t_blk)).project(bent[id(c_blk)]).gap
        worst = max(worst, float(np.nanmax(np.abs(gap))) / s)
    return worst


def bend_work(model: Model, q) -> float:
    """The work of the exact solution's interface forces (the consistent nodal forces of the
    pressure on each face, equal and opposite) on the common bend z += q(X) of both faces,
    over p: Σ a_i q(X_i) over the upper face's nodes minus the lower's (a: tributary areas).
    Both faces' FE interpolate q, so this is ∫ (I_upper q - I_lower q) dA: 0 on matching
    meshes, (h_u² - h_l²) / 6 for q = x² on [0, 1]² grids of spacings h_u and h_l."""
    return float(sum(sign * np.sum(b.area * q(b.X[b.face]))
                     for b, sign in ((model.upper, 1.0), (model.lower, -1.0))))


def pressure_shares(b: Block, kind: str, k: int = 300) -> np.ndarray:
    """The nodal forces a uniform unit pressure puts on block b's face through a contact
    with it as the target (built as `kind`): Σ_g N_j(x_g) dA over a k x k grid of points
    just inside the face (N_j: the target's shape functions in the element's 𝒩 = ∂g/∂u, the
    z part of node j's block over the contactor's). The FE's own are b.area (the face's
    shape functions integrated): node-to-facet gives them; any other transfer is off by what
    no refinement of the contactors removes."""
    from diffsurf_cli import contact

    t = (np.arange(k) + 0.5) / k
    gx, gy = np.meshgrid(t, t, indexing="ij")
    P = b.X[b.face]
    x = np.stack([gx.ravel(), gy.ravel(), np.full(k * k, P[0, 2] - 1e-9)], axis=1)
    c = contact(_surface(kind, P, _local(b)), x)
    N, nodes = np.asarray(c.N), np.asarray(c.nodes)
    share = -N[:, 5::3] / N[:, 2:3]          # ∂g/∂z_j = -N_j ν_z; ∂g/∂x_z = ν_z
    out = np.zeros(len(P))
    used = nodes >= 0
    np.add.at(out, nodes[used], share[used] / (k * k))
    return out
