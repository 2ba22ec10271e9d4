"""The paper's plate pressed and slid on the rigid faceted cylinder, with Coulomb friction
(issue 23): μ = 0.2, three ways: the diffuse surface, node-to-facet, and the exact cylinder.

The model is `plate_on_cylinder.py`'s (scikit-fem hexahedra, linear elasticity, the 65 x 20 x 5
mm plate under the 16-facet half cylinder of `sample_meshes/cylinder.msh`, R = 10): the bottom
face is pressed up by `--press` mm, then slid along x by `--slide` mm. The contactors are the
top-face nodes, with the penalty ε_i = ε x the tributary area of node i, normal and tangential
(ε_T = ε). Per penetrating contactor (`diffsurf_cli.element.friction`):

    R = ε g ν + T,   T = P(τ_n + ε_T (y − y_n)) returned onto |T| <= μ ε |g|,
    K = ε (g ∂²g/∂x² + ν νᵀ) + ∂T/∂x   (not symmetric in slip)

where y is the proximal point on the target's surface and (y_n, τ_n) the history of the last
converged step: diffsurf's `contact(surface, x, rigid_target=True, friction=Coulomb(mu),
history=h)` for the diffuse and faceted targets, the same law (`friction.coulomb`) on the
exact cylinder's g, ν, ∂²g/∂x² for the reference. Newton per step; the history is the
`Contact.history` of the step's converged iterate.

Printed: Newton iterations per step, r_{k+1}/r_k² where the active and stick sets stay, and
each law's largest deviation from the exact run, of the tangential and of the normal force,
per step, relative to the exact force of that step.

    python examples/friction_slide.py --png friction.png          # default run
    python examples/friction_slide.py --quick --png friction.png  # coarse, seconds

Needs scikit-fem (and matplotlib for --png). Logs go to stderr, the table to stdout.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp


def _sibling(name: str):
    """The example `name`.py next to this one, as a module (without touching sys.path)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parent /
                                                  f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


base = _sibling("plate_on_cylinder")  # the plate, its solver and the exact cylinder

log = logging.getLogger("friction_slide")

MU = 0.2
LAWS = ("exact", "diffuse", "facet")
#: relative residuals at round-off: r_{k+1}/r_k² is not measured below it
FLOOR = base.FLOOR


class Solver(base.CondensedSolver):
    """The plate's condensed Newton solve, for a contact tangent that is not symmetric."""

    def solve(self, Kc, r):
        import scipy.linalg

        du = np.zeros_like(r)
        rI, rT = r[self.I], r[self.T]
        rhs = rT - self.KTI @ self.lu.solve(rI)
        du[self.T] = scipy.linalg.solve(self.S + Kc[self.T][:, self.T].toarray(), -rhs)
        du[self.I] = self.lu.solve(-rI - self.KIT @ du[self.T])
        return du


# ---------------------------------------------------------------------------------------------
# The laws: (positions (m, 3), history, ε (m,)) -> Terms

@dataclass
class Terms:
    R: np.ndarray             # (n_dofs,) residual of the contactors
    K: sp.csr_matrix          # its tangent
    active: np.ndarray        # penetrating contactors
    stick: np.ndarray         # (m,) True where a penetrating contactor sticks
    history: object           # the state the next step starts from, if this one converges
    normal: np.ndarray        # (m,) ε |g|


def diffsurf_law(surface, friction):
    from diffsurf_cli import contact

    def law(x, history, eps, dofs, n_dofs):
        c = contact(surface, x, rigid_target=True, friction=friction, history=history)
        R = c.residual(eps, dofs, n_dofs=n_dofs)
        K = c.tangent(eps, dofs, n_dofs=n_dofs)
        t = c.tractions(eps)
        return Terms(R, K, c.contactor, t.stick, c.history, t.normal)

    return law


def exact_law(friction):
    """The exact cylinder (plate_on_cylinder.exact_law's g, ν, ∂²g/∂x²) and the same
    friction law on it, assembled by hand."""
    from diffsurf_cli.element.friction import History, coulomb

    def law(x, history, eps, dofs, n_dofs):
        index, gap, N, M = base.exact_law(x)
        m = len(x)
        r = x[:, :2] - base.AXIS
        d = np.hypot(r[:, 0], r[:, 1])
        y = x.copy()  # the proximal point of every contactor: on the circle, same z
        y[:, :2] = base.AXIS + base.RADIUS * r / d[:, None]
        if history is None:
            y_n, tau_n = np.full((len(index), 3), np.nan), np.zeros((len(index), 3))
        else:
            y_n, tau_n = history.proximal_point[index], history.traction[index]
        e = eps[index]
        T, dT, stick = coulomb(gap, N, M, y[index], y_n, tau_n, friction.mu, e, e)
        R = np.zeros(n_dofs)
        dd = dofs[index]
        np.add.at(R, dd, (e * gap)[:, None] * N + T)
        Kc = ((e * gap)[:, None, None] * M + e[:, None, None] * N[:, :, None] * N[:, None, :]
              + dT)
        rows = np.repeat(dd, 3, axis=1).ravel()
        cols = np.tile(dd, (1, 3)).ravel()
        K = sp.coo_matrix((Kc.ravel(), (rows, cols)), shape=(n_dofs, n_dofs)).tocsr()
        tau = np.zeros((m, 3))
        tau[index] = T
        sticks = np.zeros(m, bool)
        sticks[index] = stick
        normal = np.zeros(m)
        normal[index] = e * np.abs(gap)
        return Terms(R, K, index, sticks, History(y, tau), normal)

    return law


def make_law(name: str, mu: float):
    from diffsurf_cli import Coulomb, surface_from_file

    friction = Coulomb(mu)
    if name == "exact":
        return exact_law(friction)
    _, surface = surface_from_file(str(base.CYLINDER_MSH), method=name, feature_angle=180)
    return diffsurf_law(surface, friction)


# ---------------------------------------------------------------------------------------------
# Newton

@dataclass
class Step:
    drive: tuple
    residuals: list = field(default_factory=list)
    same: list = field(default_factory=list)      # active and stick sets as the last iterate's
    converged: bool = False
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))  # on the plate
    slipping: int = 0
    active: int = 0

    @property
    def iterations(self) -> int:
        return len(self.residuals) - 1

    def ratios(self) -> list:
        r = self.residuals
        return [r[k + 1] / r[k] ** 2 for k in range(len(r) - 1)
                if self.same[k + 1] and r[k + 1] > FLOOR]


def solve_step(plate, law, u, drive, eps, history, tol, maxit):
    """Newton on K u + R_c(u) = 0 with the bottom face at `drive`; returns (Step, history)."""
    u[plate.fixed[:, 0]] = drive[0]
    u[plate.fixed[:, 1]] = drive[1]
    u[plate.fixed[:, 2]] = 0.0
    dofs = plate.dofs[plate.top]
    step, previous = Step(tuple(drive)), None
    for k in range(maxit + 1):
        x = plate.X[plate.top] + u[dofs]
        terms = law(x, history, eps, dofs, plate.n_dofs)
        fint = plate.K @ u
        r = fint + terms.R
        rel = np.linalg.norm(r[plate.free]) / max(np.linalg.norm(fint[plate.free]),
                                                  np.linalg.norm(terms.R), 1e-300)
        sets = (frozenset(terms.active.tolist()), frozenset(np.flatnonzero(terms.stick)))
        step.residuals.append(rel)
        step.same.append(sets == previous)
        previous = sets
        if rel <= tol:
            step.converged = True
            break
        if k == maxit:
            break
        u += plate.solver.solve(terms.K, r)
    step.force = -np.array([terms.R[dofs[:, j]].sum() for j in range(3)])
    step.active = len(terms.active)
    step.slipping = len(terms.active) - int(terms.stick.sum())
    return step, terms.history


def run(quick=False, png=None, press=0.3, slide=None, n_slide=None, penalty=None, mu=MU,
        tol=1e-10, maxit=30, laws=LAWS, out=sys.stdout):
    """Solve the slide with each law; print the table; write the PNG; return the results."""
    if quick:
        fine, coarse, ny, nz, n_press = 2.5, 2.5, 5, 2, 2
        slide = 2.5 if slide is None else slide
        n_slide = 5 if n_slide is None else n_slide
    else:
        fine, coarse, ny, nz, n_press = 0.5, 2.5, 16, 2, 3
        slide = 5.0 if slide is None else slide
        n_slide = 50 if n_slide is None else n_slide
    lo, hi = base.AXIS[0] - max(slide, 0.0) - 5.0, base.AXIS[0] - min(slide, 0.0) + 5.0
    plate = base.build_plate(base.x_edges(fine, coarse, lo, hi), ny, nz)
    plate.solver = Solver(plate.K, plate.free, plate.dofs[plate.top].ravel())
    penalty = 10.0 * base.E / fine if penalty is None else penalty
    eps = penalty * plate.area
    log.info("plate: %d hexahedra, %d DOFs, %d contactors, penalty %.3g N/mm^3, mu %g",
             plate.n_cells, plate.n_dofs, len(plate.top), penalty, mu)
    steps = base.drives(press, slide, n_press, n_slide)
    results = {}
    for name in laws:
        law = make_law(name, mu)
        u, history, hist = np.zeros(plate.n_dofs), None, []
        t0 = time.process_time()
        for drive in steps:
            s, new = solve_step(plate, law, u, drive, eps, history, tol, maxit)
            if not s.converged:
                log.warning("%s: step %s did not converge in %d iterations", name, drive, maxit)
            history = new
            hist.append(s)
            log.info("%-7s drive x %6.3f y %5.3f: %2d its, %2d in contact (%2d slip), "
                     "F = (%9.4f, %9.4f) kN, r+/r^2: %s", name, *drive, s.iterations,
                     s.active, s.slipping, s.force[0] / 1e3, s.force[1] / 1e3,
                     " ".join(f"{q:.2g}" for q in s.ratios()) or "-")
        results[name] = hist
        log.info("%s: %.1f s CPU", name, time.process_time() - t0)
    summary = summarise(results, n_press, out)
    if png:
        plot(results, n_press, png, mu)
        log.info("wrote %s", png)
    return {"results": results, "summary": summary, "n_press": n_press}


def summarise(results, n_press, out) -> dict:
    """Per law: Newton iterations, the largest r_{k+1}/r_k², and the largest deviation from
    the exact run over the slide steps of the tangential (F_x) and normal (F_y) force, each
    relative to the exact force of the same step."""
    ref = results.get("exact")
    summary = {}
    print(f"{'law':8s} {'Newton its':>10s} {'max it':>6s} {'max r+/r2':>10s} "
          f"{'dFt %':>8s} {'dFn %':>8s}", file=out)
    for name, hist in results.items():
        its = [s.iterations for s in hist]
        ratios = [q for s in hist for q in s.ratios()]
        row = {"iterations": its, "converged": all(s.converged for s in hist),
               "max_ratio": max(ratios) if ratios else float("nan"),
               "slipping": [s.slipping for s in hist]}
        if ref is not None:
            F = np.array([s.force for s in hist[n_press:]])
            Fr = np.array([s.force for s in ref[n_press:]])
            row["dFt"] = 100 * float(np.max(np.abs(F[:, 0] - Fr[:, 0]) / np.abs(Fr[:, 0])))
            row["dFn"] = 100 * float(np.max(np.abs(F[:, 1] - Fr[:, 1]) / np.abs(Fr[:, 1])))
        summary[name] = row
        print(f"{name:8s} {sum(its):10d} {max(its):6d} {row['max_ratio']:10.3g} "
              f"{row.get('dFt', np.nan):8.3f} {row.get('dFn', np.nan):8.3f}", file=out)
    print("dFt, dFn: max over the slide steps of |F - F_exact| / |F_exact| of that step, "
          "tangential (x) and normal (y) force on the plate", file=out)
    for name, row in summary.items():
        print(f"Newton iterations per step, {name}: {' '.join(map(str, row['iterations']))}",
              file=out)
    return summary


def plot(results, n_press, png, mu):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    style = {"exact": dict(color="k", lw=2.5, label="exact cylinder"),
             "diffuse": dict(color="tab:blue", marker="o", ms=3, lw=1, label="diffuse (diffsurf)"),
             "facet": dict(color="tab:red", marker="s", ms=3, lw=1, label="node-to-facet")}
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.5))
    for name, hist in results.items():
        slide = np.array([s.drive[0] for s in hist[n_press - 1:]])
        F = np.array([s.force for s in hist[n_press - 1:]]) / 1e3
        ax[0].plot(slide, F[:, 0], **style[name])
        ax[1].plot(slide, -F[:, 1], **style[name])
    ax[0].set(xlabel="slide of the plate's bottom face along x [mm]",
              ylabel="tangential contact force F_x [kN]", title=f"tangential force (μ = {mu:g})")
    ax[1].set(xlabel="slide along x [mm]", ylabel="normal contact force -F_y [kN]",
              title="normal force")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle("elastic plate slid on a rigid 16-facet half cylinder (R = 10 mm), Coulomb "
                 "friction")
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Logs go to stderr, the table to stdout.")
    ap.add_argument("--quick", action="store_true", help="coarse mesh, few steps (seconds)")
    ap.add_argument("--png", help="write the force plots to this PNG")
    ap.add_argument("--mu", type=float, default=MU, help="friction coefficient (0.2)")
    ap.add_argument("--press", type=float, default=0.3, help="press of the bottom face [mm]")
    ap.add_argument("--slide", type=float, help="slide along x [mm] (5; --quick 2.5)")
    ap.add_argument("--steps", type=int, help="slide steps (50; --quick 5)")
    ap.add_argument("--penalty", type=float,
                    help="penalty per unit area [N/mm^3] (default 10 E / element size)")
    ap.add_argument("--laws", default=",".join(LAWS), help="subset of exact,diffuse,facet")
    ap.add_argument("-q", "--quiet", action="store_true", help="no log, only the table")
    a = ap.parse_args(argv)
    logging.basicConfig(stream=sys.stderr, format="%(message)s",
                        level=logging.WARNING if a.quiet else logging.INFO)
    logging.getLogger("skfem").setLevel(logging.WARNING)
    laws = [s.strip() for s in a.laws.split(",") if s.strip()]
    if set(laws) - set(LAWS):
        ap.error(f"unknown law(s): {', '.join(sorted(set(laws) - set(LAWS)))}")
    run(quick=a.quick, png=a.png, press=a.press, slide=a.slide, n_slide=a.steps,
        penalty=a.penalty, mu=a.mu, laws=laws)
    return 0


if __name__ == "__main__":
    sys.exit(main())
