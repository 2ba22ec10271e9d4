"""Two elastic bodies in contact, with the full diffuse element (issue 21): a coarse half tube
pressed onto a block.

A scikit-fem model (hexahedra, linear elasticity, small strain), arbitrary consistent units:

- the block 40 x 6 x 4 (x, y, z; E = 200, nu = 0.3), its bottom face y = 0 clamped; its top
  face's nodes are the contactors;
- the half tube above it (E = 1000, nu = 0.3): outer radius 8, wall 2, the lower half of the
  circle (θ from 190° to 350°), axis along z through (20, 6 + 8 + `GAP0`), 6 z long; its outer
  surface, meshed coarse (`--facets` quads around the half circle), is the target of the
  contact, a `DiffuseSurface` that moves with the tube (`surface.moved(nodes)`); its inner
  surface is driven down by `--press` in `--steps` steps.

Contact: the penalty [3] with ε_i = `--penalty` x the contactor's tributary area; per
penetrating contactor the full element u = [x^c, x^support...] [§4.2-4.3], R = ε g N [45],
K = ε (g M + N Nᵀ) [54], coupling block and tube. Each step freezes the pairing (frames,
supports, radii) where the step starts (`contact(...).projection.patch`) and reuses it at
every Newton iteration (`contact(moved, x, pairing=...)`): K is then the exact derivative of
R, and Newton converges quadratically wherever the set of penetrating contactors stays.

Newton's loop (`solve_step`) is one to copy: every iteration checks `c.lost` (a contactor
with no answer that the facets find penetrating stops the step: its force would be missing)
and counts the contactors without an answer; a safeguard keeps it from cycling where the set
of penetrating contactors changes within a step (the tangent is exact, but K_el + K_c can be
indefinite far from the solution): a backtracking line search on the residual's norm
(`--safeguard line-search`, the default) or the Gauss-Newton tangent on the step's first
iterations (`--safeguard gauss-newton`). Plain Newton (`--safeguard none`) cycles, period 2,
on one step pressing 0.4 from rest (`--quick --steps 1`); both safeguards converge in 5 or 6
iterations (tests/test_newton_loop.py).

Checks, printed (and asserted by tests/test_two_bodies.py in quick mode):
- Newton's residuals per step, and r_{k+1} / r_k² over iterations with an unchanged active set;
- the contact tangent against central finite differences of the residual (frozen pairing),
  at the start of the last step: the relative error, and the Taylor remainder's order;
- the balance of the contact forces: Σ f and Σ x × f over both bodies, relative to Σ |f|.

Friction (issue 33): with `--mu`, Coulomb friction acts between the bodies throughout (the
full element's: on the contactors and on the tube's nodes, `contact(..., friction=,
history=)`, each step starting from the last converged step's `c.history`); `--slide S
--slide-steps n` then slides the tube along x by S in n more steps. Printed too: how many
contactors stick and slip at the end, and on the slipping ones the largest deviation of
|F_T| from μ F_N (asserted by tests/test_two_bodies.py: <= 1e-12).

    python examples/two_bodies.py                 # default run
    python examples/two_bodies.py --quick         # coarse, a second or two
    python examples/two_bodies.py --quick --mu 0.2 --slide 1 --slide-steps 4   # a slide

Needs scikit-fem (`pip install scikit-fem`).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

LENGTH, HEIGHT, DEPTH = 40.0, 6.0, 4.0      # the block, along x, y, z
RADIUS, WALL, TUBE_LENGTH = 8.0, 2.0, 6.0    # the half tube
THETA = (190.0, 350.0)                       # its arc, degrees
GAP0 = 0.01                                  # the tube's lowest point above the block at rest
E_BLOCK, E_TUBE, NU = 200.0, 1000.0, 0.3


@dataclass
class Body:
    K: sp.csr_matrix        # linear elastic stiffness on the body's DOFs
    X: np.ndarray           # (n, 3) reference positions
    dofs: np.ndarray        # (n, 3) global DOF of each node's x, y, z


@dataclass
class Model:
    block: Body
    tube: Body
    K: sp.csr_matrix        # both bodies' stiffness, block DOFs first
    n_dofs: int
    contactors: np.ndarray  # block node of each contactor (its top face)
    area: np.ndarray        # their tributary areas
    target: np.ndarray      # tube node of each target surface node
    faces: np.ndarray       # the target's quads (target surface node indices), outward
    clamped: np.ndarray     # block bottom DOFs
    driven: np.ndarray      # tube inner-surface DOFs, (k, 3)
    free: np.ndarray


def _body(mesh, E: float, first_dof: int) -> Body:
    import skfem
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementHex1()))
    K = skfem.asm(linear_elasticity(*lame_parameters(E, NU)), basis).tocsr()
    return Body(K, mesh.p.T.copy(), basis.nodal_dofs.T.copy() + first_dof)


def build(quick: bool) -> Model:
    """Both meshes, their stiffness, the contactors and the target surface."""
    import skfem

    nx, ny, nz = (20, 2, 2) if quick else (60, 4, 6)
    block_mesh = skfem.MeshHex.init_tensor(np.linspace(0.0, LENGTH, nx + 1),
                                           np.linspace(0.0, HEIGHT, ny + 1),
                                           np.linspace(0.0, DEPTH, nz + 1))
    block = _body(block_mesh, E_BLOCK, 0)
    nt, nr, nzt = (8, 1, 2) if quick else (12, 2, 4)
    # the tube in (r, θ, z), right-handed like (x, y, z): mapped, each hexahedron keeps its
    # orientation
    tube_mesh = skfem.MeshHex.init_tensor(np.linspace(RADIUS - WALL, RADIUS, nr + 1),
                                          np.radians(np.linspace(*THETA, nt + 1)),
                                          np.linspace(DEPTH / 2 - TUBE_LENGTH / 2,
                                                      DEPTH / 2 + TUBE_LENGTH / 2, nzt + 1))
    r, t, z = tube_mesh.p
    centre = (LENGTH / 2, HEIGHT + RADIUS + GAP0)
    tube_mesh = skfem.MeshHex(np.array([centre[0] + r * np.cos(t), centre[1] + r * np.sin(t),
                                        z]), tube_mesh.t)
    tube = _body(tube_mesh, E_TUBE, 3 * len(block.X))
    n_dofs = 3 * (len(block.X) + len(tube.X))
    K = sp.block_diag([block.K, tube.K]).tocsr()
    # contactors: the block's top face, and their tributary areas (a quarter of each quad)
    top = np.flatnonzero(np.isclose(block.X[:, 1], HEIGHT))
    grid = top[np.lexsort((block.X[top, 0], block.X[top, 2]))].reshape(nz + 1, nx + 1)
    area = np.zeros(len(block.X))
    cell = (LENGTH / nx) * (DEPTH / nz)
    np.add.at(area, grid[:-1, :-1].ravel(), cell / 4)
    np.add.at(area, grid[1:, :-1].ravel(), cell / 4)
    np.add.at(area, grid[:-1, 1:].ravel(), cell / 4)
    np.add.at(area, grid[1:, 1:].ravel(), cell / 4)
    contactors = grid.ravel()
    # the target: the tube's outer surface, a structured grid of quads in (θ, z)
    rad = np.hypot(tube.X[:, 0] - centre[0], tube.X[:, 1] - centre[1])
    outer = np.flatnonzero(np.isclose(rad, RADIUS))
    theta = np.arctan2(tube.X[outer, 1] - centre[1], tube.X[outer, 0] - centre[0]) % (2 * np.pi)
    target = outer[np.lexsort((theta, tube.X[outer, 2]))]  # θ fastest, then z
    ids = np.arange(len(target)).reshape(nzt + 1, nt + 1)
    faces = np.stack([ids[:-1, :-1], ids[:-1, 1:], ids[1:, 1:], ids[1:, :-1]], -1).reshape(-1, 4)
    P = tube.X[target]
    a, b, c, d = (P[faces[:, k]] for k in range(4))
    normal = np.cross(c - a, d - b)
    mid = (a + c) / 2 - [centre[0], centre[1], 0.0]
    mid[:, 2] = 0.0
    if np.einsum("ij,ij->i", normal, mid).mean() < 0:  # outward: away from the axis
        faces = faces[:, ::-1]
    inner = np.flatnonzero(np.isclose(rad, RADIUS - WALL))
    clamped = block.dofs[np.isclose(block.X[:, 1], 0.0)].ravel()
    driven = tube.dofs[inner]
    free = np.setdiff1d(np.arange(n_dofs), np.concatenate([clamped, driven.ravel()]))
    return Model(block, tube, K, n_dofs, contactors, area[contactors], target, faces, clamped,
                 driven, free)


def _surface(model: Model, u: np.ndarray, surface=None):
    """The target surface at displacement u: built once, then `moved`."""
    from diffsurf_cli import DiffuseSurface

    nodes = model.tube.X[model.target] + u[model.tube.dofs[model.target]]
    if surface is None:
        return DiffuseSurface(nodes, [model.faces])
    return surface.moved(nodes)


def contact_terms(model: Model, u: np.ndarray, surface, pairing, penalty: float,
                  tangent: bool = True, gauss_newton: bool = False, friction=None,
                  history=None):
    """R and K of the contact (frozen `pairing`) at displacement u, on the global DOFs; with
    `gauss_newton`, K = Σ ε N Nᵀ (no M: positive semi-definite). With `friction` (a
    `Coulomb`), its tangential part too, from `history` (the last converged step's
    `c.history`; None at the first): on the contactors and on the tube's nodes."""
    from diffsurf_cli import contact

    x = model.block.X[model.contactors] + u[model.block.dofs[model.contactors]]
    c = contact(surface, x, pairing=pairing, second=tangent and not gauss_newton,
                friction=friction, history=history)
    eps = penalty * model.area
    cd = model.block.dofs[model.contactors]
    td = model.tube.dofs[model.target]
    R = c.residual(eps, cd, td, model.n_dofs)
    K = (c.tangent(eps, cd, td, model.n_dofs, gauss_newton=gauss_newton) if tangent
         else None)
    return c, R, K


@dataclass
class Step:
    press: float
    residuals: list = field(default_factory=list)   # |r_free| / |f_internal|
    active: list = field(default_factory=list)      # penetrating contactors per iteration
    same: list = field(default_factory=list)        # active set unchanged
    lengths: list = field(default_factory=list)     # the line search's step length t
    lost: int = 0                                   # contactors lost (c.lost): step stopped
    unanswered: list = field(default_factory=list)  # outside or failed contactors
    gauss_newton: list = field(default_factory=list)  # the tangent was Gauss-Newton's
    converged: bool = False

    def ratios(self, floor: float) -> list:
        """r_{k+1} / r_k² over full Newton steps (t = 1, exact tangent) with an unchanged
        active set."""
        r = self.residuals
        return [r[k + 1] / r[k] ** 2 for k in range(len(r) - 1)
                if self.same[k + 1] and r[k + 1] > floor and self.lengths[k] == 1.0
                and not self.gauss_newton[k]]


#: The Taylor remainder's steps: small enough that no contactor crosses Coulomb's cone (from
#: stick to slip) or leaves contact within them, where R has a kink and the order falls to 1.
TAYLOR_STEPS = (1e-4, 5e-5)


def finite_difference_check(model: Model, u: np.ndarray, surface, pairing, penalty: float,
                            seed: int = 0, friction=None, history=None) -> dict:
    """K d against central differences of R (frozen pairing) along a random d on the DOFs of
    the contactors and the target nodes; the Taylor remainder |R(u + h d) − R(u) − h K d| at
    h and h/2 (order ≈ 2)."""
    rng = np.random.default_rng(seed)
    d = np.zeros(model.n_dofs)
    moving = np.concatenate([model.block.dofs[model.contactors].ravel(),
                             model.tube.dofs[model.target].ravel()])
    d[moving] = rng.standard_normal(len(moving))
    c, R0, K = contact_terms(model, u, surface, pairing, penalty, friction=friction,
                             history=history)

    def residual(v):
        moved = _surface(model, v, surface)
        return contact_terms(model, v, moved, pairing, penalty, tangent=False,
                             friction=friction, history=history)[1]

    h = 1e-7
    Kd = K @ d
    fd = (residual(u + h * d) - residual(u - h * d)) / (2 * h)
    remainders = [np.linalg.norm(residual(u + s * d) - R0 - s * Kd) for s in TAYLOR_STEPS]
    with np.errstate(divide="ignore", invalid="ignore"):  # no element yet: NaN, not measured
            return {"elements": len(c),
                "relative error": np.linalg.norm(fd - Kd) / np.linalg.norm(Kd),
                "order": np.log2(remainders[0] / remainders[1])}


def balance(model: Model, R: np.ndarray, u: np.ndarray) -> dict:
    """Σ f and Σ x × f of the contact forces f = −R over both bodies, relative to Σ |f|."""
    f = -R
    nodes = np.concatenate([model.block.dofs, model.tube.dofs])
    X = np.concatenate([model.block.X, model.tube.X]) + u[nodes]
    F = f[nodes]
    scale = np.abs(F).sum() * (1.0 + np.abs(X).max())
    with np.errstate(invalid="ignore"):  # no contact force: NaN, not measured
            return {"force": np.abs(F.sum(axis=0)).max() / np.abs(F).sum(),
                "moment": np.abs(np.cross(X, F).sum(axis=0)).max() / scale,
                "on the block": F[:len(model.block.X)].sum(axis=0)}


#: The safeguards of `solve_step`: none (plain Newton), a backtracking line search on the
#: residual's norm, or the Gauss-Newton tangent on the step's first iterations.
SAFEGUARDS = (None, "line-search", "gauss-newton")
GAUSS_NEWTON_ITERATIONS = 3   # iterations on the Gauss-Newton tangent, with "gauss-newton"
ARMIJO = 1e-4                 # sufficient decrease of the line search: |r| <= (1 - ARMIJO t)|r0|
SHORTEST = 1.0 / 64           # the line search's shortest step


def solve_step(model: Model, u: np.ndarray, surface, pairing, penalty: float, drive: float,
               tol: float = 1e-10, maxit: int = 15, safeguard: str | None = "line-search",
               friction=None, history=None):
    """Newton's iterations of one load step, from u (updated in place), the pairing frozen;
    returns (Step, contact, R, surface) at the last iterate.

    Each iteration checks what the element says before trusting it: a contactor in `c.lost`
    (no answer, but the facets find it penetrating) stops the step unconverged (the caller
    cuts it), and the contactors without an answer (outside or failed) are recorded. The
    `safeguard` keeps Newton from cycling when the active set changes within a step (the
    tangent is exact, but K_el + K_c can be indefinite away from the solution): with
    "line-search", u + t du with t halved from 1 until the residual's norm falls by
    ARMIJO t (at least SHORTEST); with "gauss-newton", the first GAUSS_NEWTON_ITERATIONS
    iterations take the Gauss-Newton tangent Σ ε N Nᵀ (positive semi-definite), then the
    exact one (quadratic). `friction`, `history`: as `contact_terms`."""
    from diffsurf_cli.projection import FAILED, OUTSIDE

    if safeguard not in SAFEGUARDS:
        raise ValueError(f"safeguard must be one of {SAFEGUARDS}, got {safeguard!r}")
    step, previous = Step(drive), None

    def norm(r):
        return np.linalg.norm(r[model.free])

    for k in range(maxit + 1):
        surface = _surface(model, u, surface)
        gn = safeguard == "gauss-newton" and k < GAUSS_NEWTON_ITERATIONS
        c, R, Kc = contact_terms(model, u, surface, pairing, penalty, gauss_newton=gn,
                                 friction=friction, history=history)
        fint = model.K @ u
        r = fint + R
        scale = max(np.linalg.norm(fint[model.free]), np.linalg.norm(R), 1e-300)
        step.residuals.append(norm(r) / scale)
        active = frozenset(c.contactor.tolist())
        step.active.append(len(active))
        step.same.append(active == previous)
        step.unanswered.append(int(np.sum((c.status == OUTSIDE) | (c.status == FAILED))))
        previous = active
        if len(c.lost):  # no answer where the facets find a penetration: the force is missing
            step.lost = len(c.lost)
            break
        if step.residuals[-1] <= tol:
            step.converged = True
            break
        if k == maxit:
            break
        A = (model.K + Kc)[model.free][:, model.free].tocsc()
        du = -spla.spsolve(A, r[model.free])
        t = 1.0
        if safeguard == "line-search":
            r0 = norm(r)
            while t > SHORTEST:
                v = u.copy()
                v[model.free] += t * du
                moved = _surface(model, v, surface)
                Rv = contact_terms(model, v, moved, pairing, penalty, tangent=False,
                                   friction=friction, history=history)[1]
                if norm(model.K @ v + Rv) <= (1.0 - ARMIJO * t) * r0:
                    break
                t /= 2.0
        step.lengths.append(t)
        step.gauss_newton.append(gn)
        u[model.free] += t * du
    return step, c, R, surface


def run(quick: bool = False, press: float = 0.4, steps: int | None = None,
        penalty: float = 2e3, tol: float = 1e-10, maxit: int = 15, out=sys.stdout,
        safeguard: str | None = "line-search", mu: float = 0.0, slide: float = 0.0,
        slide_steps: int = 0) -> dict:
    """Press the tube onto the block, then (with `slide_steps`) slide it along x by `slide`;
    with `mu` > 0, Coulomb friction throughout (the full element's: on the contactors and on
    the tube's nodes). Returns the steps, the finite-difference check (at the last step's
    start) and the force balance at the end, and with friction the tractions' check.
    `safeguard`: `solve_step`'s (None: plain Newton)."""
    from diffsurf_cli import Coulomb, contact

    steps = steps or (3 if quick else 6)
    model = build(quick)
    u = np.zeros(model.n_dofs)
    surface = _surface(model, u)
    friction = Coulomb(mu) if mu > 0 else None
    history, fd, start = [], None, None
    drives = [(0.0, -press * s / steps) for s in range(1, steps + 1)]
    drives += [(slide * s / slide_steps, -press) for s in range(1, slide_steps + 1)]
    for s, (along, drive) in enumerate(drives, 1):
        u[model.driven[:, 0]], u[model.driven[:, 1]] = along, drive
        surface = _surface(model, u, surface)
        # the pairing of this step, where it starts
        x = model.block.X[model.contactors] + u[model.block.dofs[model.contactors]]
        pairing = contact(surface, x, second=False).projection.patch
        if s == len(drives):
            fd = finite_difference_check(model, u, surface, pairing, penalty,
                                         friction=friction, history=start)
        step, c, R, surface = solve_step(model, u, surface, pairing, penalty, drive, tol, maxit,
                                         safeguard, friction, start)
        history.append(step)
        if friction is not None:
            start = c.history  # the state the next step's friction starts from
        print(f"step {s}: press {-drive:.3f}, slide {along:.3f}, {step.active[-1]} "
              f"contactors in contact, Newton {len(step.residuals) - 1} iterations: "
              + " ".join(f"{v:.1e}" for v in step.residuals)
              + (f"; {step.lost} contactors lost: cut the step" if step.lost else "")
              + ("" if step.converged or step.lost else ": not converged"), file=out)
    bal = balance(model, R, u)
    slip = None if friction is None else coulomb_check(c, penalty * model.area, mu)
    ratios = [q for st in history for q in st.ratios(1e3 * tol)]
    print(f"tangent vs finite differences (last step's start, {fd['elements']} elements): "
          f"relative error {fd['relative error']:.1e}, Taylor remainder order "
          f"{fd['order']:.2f}", file=out)
    print(f"r_k+1 / r_k^2 with an unchanged active set: max {max(ratios, default=np.nan):.2g}",
          file=out)
    print(f"balance of the contact forces: |Σ f| / Σ|f| = {bal['force']:.1e}, "
          f"|Σ x × f| / (Σ|f| |x|) = {bal['moment']:.1e}; force on the block "
          f"{np.round(bal['on the block'], 4)}", file=out)
    if slip is not None:
        print(f"friction (μ = {mu}): {slip['stick']} contactors stick, {slip['slip']} slip; "
              f"on the slipping ones max ||F_T| − μ F_N| / (μ F_N) = {slip['error']:.1e}",
              file=out)
    return {"steps": history, "fd": fd, "balance": bal, "ratios": ratios, "model": model,
            "slip": slip}


def coulomb_check(c, eps, mu: float) -> dict:
    """How many of the contactors with an element stick and slip, and on the slipping ones
    the largest relative deviation of |F_T| from μ F_N (Coulomb's law: 0 to round-off)."""
    t = c.tractions(eps)
    held = np.zeros(len(t.normal), bool)
    held[c.contactor] = True
    slipping = held & ~t.stick & (t.normal > 0)
    size = np.linalg.norm(t.tangential, axis=1)
    error = np.abs(size - mu * t.normal)[slipping] / (mu * t.normal[slipping])
    return {"stick": int((held & t.stick).sum()), "slip": int(slipping.sum()),
            "error": float(error.max(initial=0.0))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="coarse meshes, 3 steps")
    ap.add_argument("--press", type=float, default=0.4)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--penalty", type=float, default=2e3,
                    help="ε per unit tributary area of a contactor")
    ap.add_argument("--safeguard", choices=["none", "line-search", "gauss-newton"],
                    default="line-search", help="Newton's safeguard (solve_step)")
    ap.add_argument("--mu", type=float, default=0.0,
                    help="Coulomb friction coefficient (0: frictionless)")
    ap.add_argument("--slide", type=float, default=0.0,
                    help="after pressing, slide the tube along x by this much")
    ap.add_argument("--slide-steps", type=int, default=0, help="in this many steps")
    args = ap.parse_args(argv)
    res = run(args.quick, args.press, args.steps, args.penalty,
              safeguard=None if args.safeguard == "none" else args.safeguard, mu=args.mu,
              slide=args.slide, slide_steps=args.slide_steps)
    return 0 if all(s.converged for s in res["steps"]) else 1


if __name__ == "__main__":
    sys.exit(main())
