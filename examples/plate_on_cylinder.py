"""The paper's example [§5], for real: an elastic plate pressed and slid on a rigid faceted
cylinder.

A scikit-fem model (hexahedra, linear elasticity, small strain) of the 65 x 20 x 5 mm plate of
`sample_meshes/` (E = 200000 MPa, nu = 0.3, mm / N / MPa). The rigid half cylinder of
`sample_meshes/cylinder.msh` (radius 10, axis z through x = 32.5, y = 30, 16 facets over the
half circle) is fixed; the plate's bottom face y = 0 is driven: pressed up by `--press` mm, then
slid along x by `--slide` mm. The contactors are the plate's top-face nodes; contact is a penalty
(eps_i = eps * tributary area of node i): for each penetrating contactor (g < 0)

    R = eps_i g N [45],   K = eps_i (g M + N N^T) [54]

with N = dg/dx^c and M = d2g/dx^c2 (the target is rigid: only the contactor's 3 DOFs). The same
mesh and steps are solved with three contact laws: the diffuse element (diffsurf), node-to-facet
(diffsurf's FacetSurface) and the exact cylinder (g, N, M by hand) as the reference. Newton per
step, no re-pairing loop: every iteration asks the library about the current contactor positions.

    python examples/plate_on_cylinder.py --png plate.png          # default (finer) run
    python examples/plate_on_cylinder.py --quick --png plate.png  # coarse, a few seconds

Logs (Newton residuals per iteration) go to stderr, the summary table to stdout.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.optimize
import scipy.sparse as sp
import scipy.sparse.linalg as spla

log = logging.getLogger("plate_on_cylinder")

ROOT = Path(__file__).resolve().parent.parent
CYLINDER_MSH = ROOT / "sample_meshes" / "cylinder.msh"
AXIS = np.array([32.5, 30.0])  # the cylinder's axis (along z) in the x-y plane
RADIUS = 10.0
LENGTH, HEIGHT, WIDTH = 65.0, 20.0, 5.0  # plate, along x, y, z
E, NU = 200000.0, 0.3
LAWS = ("exact", "diffuse", "facet")


# ---------------------------------------------------------------------------------------------
# The contact laws: (m, 3) contactor positions -> (index, gap, N (k, 3), M (k, 3, 3)) of the
# penetrating contactors (g < 0) only.

def contact_law(surface, x):
    """Every diffsurf call of this example: the element of each penetrating contactor on the
    rigid target (diffuse or node-to-facet), restricted to the contactor's unknowns.

    `rigid_target=True` gives g, N = dg/dx^c and M = d2g/dx^c2 on one fixed surface: the gap is
    a smooth function of the contactor's position alone, so Newton needs no re-pairing loop and
    sees the exact derivative of the gap it solves for (quadratic convergence).
    """
    from diffsurf_cli import contact

    c = contact(surface, x, rigid_target=True)
    return c.contactor, c.gap, c.N, c.M


def exact_law(x):
    """The exact cylinder: g = |p - a|_perp - R (distance to the axis minus the radius),
    N = n = (p - a)_perp / d, M = (P_perp - n n^T) / d (P_perp projects on the x-y plane)."""
    r = x[:, :2] - AXIS
    d = np.hypot(r[:, 0], r[:, 1])
    gap = d - RADIUS
    index = np.flatnonzero(gap < 0)
    d, r, gap = d[index], r[index], gap[index]
    n = np.zeros((len(index), 3))
    n[:, :2] = r / d[:, None]
    P = np.diag([1.0, 1.0, 0.0])
    M = (P - n[:, :, None] * n[:, None, :]) / d[:, None, None]
    return index, gap, n, M


def make_law(name: str):
    if name == "exact":
        return exact_law
    from diffsurf_cli import surface_from_file

    # one surface over the whole target (the cylinder has no sharp edge)
    _, surface = surface_from_file(str(CYLINDER_MSH), method=name, feature_angle=180)
    return lambda x: contact_law(surface, x)


# ---------------------------------------------------------------------------------------------
# The plate

def graded(n: int, total: float, top: float) -> np.ndarray:
    """n layers over [0, total], geometric, the top one `top` thick (fine under the contact)."""
    if n * top >= total:
        return np.linspace(0.0, total, n + 1)
    ratio = scipy.optimize.brentq(lambda q: top * (q**n - 1) / (q - 1) - total, 1.0 + 1e-9, 10.0)
    h = top * ratio ** np.arange(n)[::-1]
    return np.concatenate([[0.0], np.cumsum(h)]) * (total / h.sum())


def x_edges(fine: float, coarse: float, lo: float, hi: float) -> np.ndarray:
    """Cell edges along x: `fine` over [lo, hi] (where the contact travels), `coarse` outside."""
    left = np.linspace(0.0, lo, max(1, round(lo / coarse)) + 1)
    mid = np.linspace(lo, hi, max(1, round((hi - lo) / fine)) + 1)
    right = np.linspace(hi, LENGTH, max(1, round((LENGTH - hi) / coarse)) + 1)
    return np.unique(np.concatenate([left, mid, right]))


class CondensedSolver:
    """Newton's linear solves by static condensation on the top face (exact, not approximate):
    contact adds stiffness only to the top-face DOFs T, so the elastic interior I is factorised
    once and each iteration solves the dense Schur complement S + K_c,TT, with
    S = K_TT - K_TI K_II^-1 K_IT."""

    def __init__(self, K: sp.csr_matrix, free: np.ndarray, top: np.ndarray):
        self.T = np.intersect1d(top, free)
        self.I = np.setdiff1d(free, self.T)
        KII = K[self.I][:, self.I].tocsc()
        self.KIT = K[self.I][:, self.T].tocsr()
        self.KTI = K[self.T][:, self.I].tocsr()
        self.lu = spla.splu(KII)
        self.S = K[self.T][:, self.T].toarray() - self.KTI @ self.lu.solve(self.KIT.toarray())
        self.S = 0.5 * (self.S + self.S.T)

    def solve(self, Kc: sp.csr_matrix, r: np.ndarray) -> np.ndarray:
        """du on the free DOFs of (K + Kc) du = -r (Kc nonzero on T only), as a full vector."""
        import scipy.linalg

        du = np.zeros_like(r)
        rI, rT = r[self.I], r[self.T]
        rhs = rT - self.KTI @ self.lu.solve(rI)
        A = self.S + Kc[self.T][:, self.T].toarray()
        du[self.T] = scipy.linalg.solve(A, -rhs, assume_a="sym")
        du[self.I] = self.lu.solve(-rI - self.KIT @ du[self.T])
        return du


@dataclass
class Plate:
    K: sp.csr_matrix          # linear elastic stiffness
    X: np.ndarray             # (n_nodes, 3) reference positions
    dofs: np.ndarray          # (n_nodes, 3) the DOF of each node's x, y, z
    top: np.ndarray           # top-face nodes (the contactors), sorted by z then x
    area: np.ndarray          # their tributary areas
    fixed: np.ndarray         # bottom-face DOFs (driven), as (k, 3)
    free: np.ndarray          # the other DOFs
    n_dofs: int
    solver: CondensedSolver
    n_cells: int


def build_plate(xs: np.ndarray, ny: int, nz: int) -> Plate:
    """The plate meshed by hexahedra on the x edges `xs`, ny layers graded towards the top face
    (its top layer as thick as the finest x cell), nz layers across."""
    import skfem
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    mesh = skfem.MeshHex.init_tensor(xs, graded(ny, HEIGHT, np.diff(xs).min()),
                                     np.linspace(0.0, WIDTH, nz + 1))
    basis = skfem.Basis(mesh, skfem.ElementVector(skfem.ElementHex1()))
    K = skfem.asm(linear_elasticity(*lame_parameters(E, NU)), basis).tocsr()
    X = mesh.p.T.copy()
    dofs = basis.nodal_dofs.T.copy()
    top = np.flatnonzero(np.isclose(X[:, 1], HEIGHT))
    top = top[np.lexsort((X[top, 0], X[top, 2]))]
    # tributary areas: the lumped integral of each node's shape function over the top face
    facets = mesh.facets_satisfying(lambda x: np.isclose(x[1], HEIGHT))
    fb = skfem.FacetBasis(mesh, skfem.ElementHex1(), facets=facets)
    area = skfem.asm(skfem.LinearForm(lambda v, w: v), fb)[top]
    bottom = np.flatnonzero(np.isclose(X[:, 1], 0.0))
    fixed = dofs[bottom]
    free = np.setdiff1d(np.arange(basis.N), fixed.ravel())
    solver = CondensedSolver(K, free, dofs[top].ravel())
    return Plate(K, X, dofs, top, area, fixed, free, basis.N, solver, mesh.t.shape[1])


# ---------------------------------------------------------------------------------------------
# Newton

@dataclass
class Step:
    drive: tuple              # (slide, press) of the bottom face
    residuals: list           # relative residual |r_free| / |f| per iteration
    active: list              # number of penetrating contactors per iteration
    same: list                # active set unchanged from the previous iteration
    converged: bool = False
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))  # on the plate
    pressure: np.ndarray | None = None  # per top node (0 where open)
    positions: np.ndarray | None = None  # top nodes' current positions

    @property
    def iterations(self) -> int:
        return len(self.residuals) - 1

    def ratios(self, floor: float) -> list:
        """r_{k+1} / r_k^2 over the iterations where the active set did not change (Newton's
        quadratic regime of a smooth law) and r_{k+1} is above the round-off floor."""
        r = self.residuals
        return [r[k + 1] / r[k] ** 2 for k in range(len(r) - 1)
                if self.same[k + 1] and r[k + 1] > floor]


def contact_terms(plate: Plate, law, u: np.ndarray, penalty: float):
    """The penalty contributions of the penetrating contactors at displacement u:
    R = eps g N [45], K = eps (g M + N N^T) [54] on their DOFs."""
    top_dofs = plate.dofs[plate.top]
    x = plate.X[plate.top] + u[top_dofs]
    index, gap, N, M = law(x)
    eps = penalty * plate.area[index]
    R = np.zeros(plate.n_dofs)
    d = top_dofs[index]  # (k, 3)
    np.add.at(R, d, (eps * gap)[:, None] * N)
    Kc = (eps * gap)[:, None, None] * M + eps[:, None, None] * N[:, :, None] * N[:, None, :]
    rows = np.repeat(d, 3, axis=1).ravel()
    cols = np.tile(d, (1, 3)).ravel()
    Kt = sp.coo_matrix((Kc.ravel(), (rows, cols)), shape=(plate.n_dofs,) * 2).tocsr()
    return index, gap, R, Kt, x


def solve_step(plate: Plate, law, u: np.ndarray, drive, penalty: float, tol: float,
               maxit: int, name: str) -> Step:
    """Newton on r(u) = K u + R_c(u) = 0 with the bottom face at `drive` (slide, press)."""
    u[plate.fixed[:, 0]] = drive[0]
    u[plate.fixed[:, 1]] = drive[1]
    u[plate.fixed[:, 2]] = 0.0
    step = Step(tuple(drive), [], [], [])
    free = plate.free
    previous = None
    for k in range(maxit + 1):
        index, gap, R, Kt, x = contact_terms(plate, law, u, penalty)
        fint = plate.K @ u
        r = fint + R
        scale = max(np.linalg.norm(fint[free]), np.linalg.norm(R), 1e-300)
        rel = np.linalg.norm(r[free]) / scale
        active = frozenset(index.tolist())
        step.residuals.append(rel)
        step.active.append(len(index))
        step.same.append(active == previous)
        previous = active
        log.debug("%s step %s it %d: |r|/|f| = %.3e, %d in contact", name, drive, k, rel,
                  len(index))
        if rel <= tol:
            step.converged = True
            break
        if k == maxit:
            break
        u += plate.solver.solve(Kt, r)
    # force of the cylinder on the plate: -R (R is the gradient of the penalty energy)
    step.force = -np.array([R[plate.dofs[plate.top, j]].sum() for j in range(3)])
    pressure = np.zeros(len(plate.top))
    pressure[index] = -penalty * gap  # eps_i |g| / area_i
    step.pressure = pressure
    step.positions = x
    return step


def drives(press: float, slide: float, n_press: int, n_slide: int):
    out = [(0.0, press * (i + 1) / n_press) for i in range(n_press)]
    out += [(slide * (i + 1) / n_slide, press) for i in range(n_slide)]
    return out


def run(quick: bool = False, png: str | None = None, press: float = 0.3, slide: float | None = None,
        n_slide: int | None = None, penalty: float | None = None, tol: float = 1e-10,
        maxit: int = 30, laws=LAWS, out=sys.stdout):
    """Solve the example with each law; print the table; write the PNG; return the results."""
    if quick:  # uniform 2.5 mm cells: one contactor row in contact, seconds
        fine, coarse, ny, nz, n_press = 2.5, 2.5, 5, 2, 2
        slide = 2.5 if slide is None else slide  # one node spacing, in fifths
        n_slide = 5 if n_slide is None else n_slide
    else:  # 0.5 mm cells where the contact travels, 2.5 mm elsewhere
        fine, coarse, ny, nz, n_press = 0.5, 2.5, 16, 2, 3
        # 0.1 mm steps: five per node spacing, so the plot resolves the period with which the
        # top-face nodes pass under the cylinder (steps of half a spacing would alias it)
        slide = 5.0 if slide is None else slide
        n_slide = 50 if n_slide is None else n_slide
    # the material points under the cylinder's axis x = 32.5 go to 32.5 - slide
    lo, hi = AXIS[0] - max(slide, 0.0) - 5.0, AXIS[0] - min(slide, 0.0) + 5.0
    plate = build_plate(x_edges(fine, coarse, lo, hi), ny, nz)
    penalty = 10.0 * E / fine if penalty is None else penalty  # N/mm^3: pressure per penetration
    log.info("plate: %d hexahedra (%d layers in y, %d in z), %d DOFs, %d contactors, "
             "penalty %.3g N/mm^3", plate.n_cells, ny, nz, plate.n_dofs, len(plate.top), penalty)
    steps = drives(press, slide, n_press, n_slide)
    results = {}
    for name in laws:
        law = make_law(name)
        u = np.zeros(plate.n_dofs)
        t0 = time.process_time()
        history = []
        for drive in steps:
            s = solve_step(plate, law, u, drive, penalty, tol, maxit, name)
            history.append(s)
            log.info("%-7s drive x %6.3f y %5.3f: %2d Newton its, %2d in contact, "
                     "F = (%9.3f, %9.3f) kN, |r|/|f|: %s; r+/r^2: %s", name, *drive, s.iterations,
                     s.active[-1], s.force[0] / 1e3, s.force[1] / 1e3,
                     " ".join(f"{r:.1e}" for r in s.residuals),
                     " ".join(f"{q:.2g}" for q in s.ratios(FLOOR)) or "-")
            if not s.converged:
                log.warning("%s: step %s did not converge in %d iterations", name, drive, maxit)
        results[name] = history
        log.info("%s: %.1f s CPU", name, time.process_time() - t0)
    summary = summarise(results, n_press, tol, out)
    if png:
        plot(results, n_press, png, penalty)
        log.info("wrote %s", png)
    return {"results": results, "summary": summary, "n_press": n_press, "plate": plate,
            "penalty": penalty}


# relative residuals below this are at round-off (it sits at 1e-13..4e-13 in these runs, the
# penalty's conditioning): a ratio r_{k+1}/r_k^2 with r_{k+1} there measures noise, not Newton
FLOOR = 1e-11


def summarise(results, n_press: int, tol: float, out) -> dict:
    """Newton counts, the largest r_{k+1}/r_k^2, and each law's deviation from the exact one."""
    summary = {}
    ref = results.get("exact")
    if ref is not None:
        Fref = np.array([s.force for s in ref])
        fscale = np.abs(Fref[:, 1]).max()
        pscale = max(s.pressure.max() for s in ref)
    print(f"{'law':8s} {'Newton its':>10s} {'max it':>6s} {'max r+/r2':>10s} "
          f"{'dFn %':>8s} {'dFt %':>8s} {'dFt kN':>8s} {'dp %':>7s}", file=out)
    for name, hist in results.items():
        its = [s.iterations for s in hist]
        ratios = [q for s in hist for q in s.ratios(FLOOR)]
        row = {"iterations": its, "converged": all(s.converged for s in hist),
               "max_ratio": max(ratios) if ratios else float("nan")}
        if ref is not None:
            F = np.array([s.force for s in hist])
            row["dFn"] = 100 * np.abs(F[:, 1] - Fref[:, 1]).max() / fscale
            row["dFt"] = 100 * np.abs(F[:, 0] - Fref[:, 0]).max() / fscale
            row["dFt_kN"] = np.abs(F[:, 0] - Fref[:, 0]).max() / 1e3
            row["dp"] = 100 * max(np.abs(s.pressure - r.pressure).max()
                                  for s, r in zip(hist, ref)) / pscale
        summary[name] = row
        print(f"{name:8s} {sum(its):10d} {max(its):6d} {row['max_ratio']:10.3g} "
              f"{row.get('dFn', np.nan):8.3f} {row.get('dFt', np.nan):8.3f} "
              f"{row.get('dFt_kN', np.nan):8.3f} {row.get('dp', np.nan):7.2f}", file=out)
    print("dF: max over steps of |F - F_exact| in % of the exact normal force "
          f"({fscale / 1e3:.1f} kN); dp: max nodal pressure deviation in % of the exact peak "
          f"pressure ({pscale:.0f} MPa)" if ref is not None else "", file=out)
    for name, row in summary.items():
        print(f"Newton iterations per step, {name}: {' '.join(map(str, row['iterations']))}",
              file=out)
    return summary


def plot(results, n_press: int, png: str, penalty: float):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    style = {"exact": dict(color="k", lw=2.5, label="exact cylinder"),
             "diffuse": dict(color="tab:blue", marker="o", ms=3, lw=1, label="diffuse (diffsurf)"),
             "facet": dict(color="tab:red", marker="s", ms=3, lw=1, label="node-to-facet")}
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.5))
    for name, hist in results.items():
        slide = np.array([s.drive[0] for s in hist[n_press - 1:]])
        F = np.array([s.force for s in hist[n_press - 1:]]) / 1e3
        ax[0].plot(slide, -F[:, 1], **style[name])
        ax[1].plot(slide, F[:, 0], **style[name])
    ax[0].set(xlabel="slide of the plate's bottom face along x [mm]",
              ylabel="normal contact force -F_y [kN]", title="normal force (sum over contactors)")
    ax[1].set(xlabel="slide along x [mm]", ylabel="tangential contact force F_x [kN]",
              title="tangential force (frictionless: from the normal's tilt)")
    # pressure profile along x at the last step, on the middle row of contactors
    for name, hist in results.items():
        s = hist[-1]
        z = s.positions[:, 2]
        row = np.isclose(z, np.median(np.unique(np.round(z, 6))), atol=1e-3)
        order = np.argsort(s.positions[row, 0])
        ax[2].plot(s.positions[row, 0][order], s.pressure[row][order], **style[name])
    sl = results[next(iter(results))][-1].drive[0]
    ax[2].set(xlabel="x of the contactor [mm]", ylabel="contact pressure eps |g| [MPa]",
              title=f"pressure profile at slide {sl:g} mm (middle row)")
    xs = [s.positions[s.pressure > 0, 0] for h in results.values() for s in h[-1:]]
    xs = np.concatenate(xs)
    if xs.size:
        ax[2].set_xlim(xs.min() - 3, xs.max() + 3)
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(f"elastic plate on a rigid 16-facet half cylinder (R = {RADIUS:g} mm), "
                 f"penalty {penalty:.3g} N/mm$^3$")
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Logs go to stderr, the summary table to stdout.")
    ap.add_argument("--quick", action="store_true", help="coarse mesh, few steps (seconds)")
    ap.add_argument("--png", help="write the force and pressure plots to this PNG")
    ap.add_argument("--press", type=float, default=0.3, help="press of the bottom face [mm]")
    ap.add_argument("--slide", type=float, help="slide along x [mm] (5; --quick 2.5)")
    ap.add_argument("--steps", type=int, help="slide steps (50; --quick 5)")
    ap.add_argument("--penalty", type=float,
                    help="penalty eps per unit area [N/mm^3] (default 10 E / element size)")
    ap.add_argument("--tol", type=float, default=1e-10, help="Newton: |r_free| / |f| (1e-10)")
    ap.add_argument("--laws", default=",".join(LAWS), help="comma-separated subset of "
                    "exact,diffuse,facet")
    ap.add_argument("-v", "--verbose", action="store_true", help="log every Newton iteration")
    ap.add_argument("-q", "--quiet", action="store_true", help="no log, only the table")
    a = ap.parse_args(argv)
    logging.basicConfig(stream=sys.stderr, format="%(message)s",
                        level=logging.WARNING if a.quiet else
                        logging.DEBUG if a.verbose else logging.INFO)
    logging.getLogger("skfem").setLevel(logging.WARNING)  # its assembly chatter
    laws = [s.strip() for s in a.laws.split(",") if s.strip()]
    bad = set(laws) - set(LAWS)
    if bad:
        ap.error(f"unknown law(s): {', '.join(sorted(bad))}")
    run(quick=a.quick, png=a.png, press=a.press, slide=a.slide, n_slide=a.steps,
        penalty=a.penalty, tol=a.tol, laws=laws)
    return 0


if __name__ == "__main__":
    sys.exit(main())
