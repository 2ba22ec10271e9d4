"""Newton solve of a row of contactors sliding around the rigid faceted cylinder (paper §5 in
miniature): diffuse contact element vs node-to-facet.

Scene: sample_meshes/cylinder.msh (lower half cylinder, radius 10 mm, axis z through x = 32.5,
y = 30; 16 facets of 11.25° around, 4 along z). A row of 4 contactor nodes along z (z = 0.6,
1.25, 3.75, 4.4: away from the facet-edge planes z = 0, 2.5, 5) is tied by springs k_s to
prescribed positions DEPTH = 0.5 mm inside the exact cylinder along the radius at angle θ; θ is
swept over 4 facets (edges at 258.75°, 270°, 281.25°). Unknowns: the contactor positions.

    Π(x) = Σ ½ k_s |x_i - y_i|² + Σ ε g_i²/2 (closed contacts),  ε = 30 k_s
    Newton: (k_s I + K_cc) Δx = -(k_s (x - y) + R_c), R_c, K_cc from contact(...) each iteration

Schemes: 'facet' (node-to-facet, pairing searched every iteration), 'diffuse' (default options:
the auto frame is 'local' here; pairing searched every iteration), 'diffuse-frozen' (same
surface, pairing searched at the start of each step and frozen within its Newton loop: exact
Newton), 'diffuse-global' (global frame, pairing searched every iteration).

The exact cylinder is rotationally symmetric, so the exact contact force is the same at every θ:
the oscillation amplitude is (max - min) / mean of the radial force over the slide, not
detrended; the tangential force (along e_θ) should be 0, its range is given relative to the mean
radial force.

Run: python benchmarks/newton_slide.py
"""
from __future__ import annotations

import os
import time

import numpy as np

from diffsurf_cli import io
from diffsurf_cli.element.element import contact
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.frame import corner_faces
from diffsurf_cli.mls.surface import DiffuseSurface

HERE = os.path.dirname(os.path.abspath(__file__))
CYLINDER = os.path.join(HERE, os.pardir, "sample_meshes", "cylinder.msh")
AXIS = np.array([32.5, 30.0])
RADIUS = 10.0
ZS = np.array([0.6, 1.25, 3.75, 4.4])
DEPTH = 0.5
KS = 1.0
PENALTY = 30.0 * KS
FORCE = KS * DEPTH
TOL = 1e-11 * FORCE
THETAS = np.arange(247.5, 292.51, 0.5)
EDGES = (258.75, 270.0, 281.25)
SHOW_HISTORY = (247.5, 258.5, 270.5, 280.0)


def target():
    tgt = io.read_target(CYLINDER)
    nodes = tgt.points[tgt.nodes]
    faces = [np.searchsorted(tgt.nodes, f) for f in corner_faces(tgt.cells)]
    return nodes, faces


def prescribed(theta_deg):
    t = np.radians(theta_deg)
    r = RADIUS - DEPTH
    one = np.ones_like(ZS)
    return np.column_stack([AXIS[0] + r * np.cos(t) * one, AXIS[1] + r * np.sin(t) * one, ZS])


def newton(surf, y, x0, freeze=False, maxit=40):
    n = len(y)
    dofs = np.arange(3 * n).reshape(n, 3)
    x = x0.copy()
    history, pairing = [], None
    for _ in range(maxit):
        c = contact(surf, x, pairing=pairing)
        if freeze and pairing is None:
            pairing = c.projection.patch
        R = c.residual(PENALTY, dofs)  # the target is fixed: no target DOFs
        K = c.tangent(PENALTY, dofs).toarray()
        r = KS * (x - y).ravel() + R
        history.append(float(np.linalg.norm(r)))
        if history[-1] <= TOL:
            break
        x = x + np.linalg.solve(KS * np.eye(3 * n) + K, -r).reshape(n, 3)
    return x, history, c


def rates(history):
    """Near the solution (r_k < 0.1 FORCE, r_{k+1} above round-off 1e-12 FORCE): the ratios
    r_{k+1}/r_k (linear rate) and r_{k+1}/r_k² (bounded for quadratic convergence)."""
    lin, quad = [], []
    for a, b in zip(history[:-1], history[1:]):
        if a < 0.1 * FORCE and b > 1e-12 * FORCE:
            lin.append(b / a)
            quad.append(b / a**2)
    return lin, quad


def sweep(name, surf, freeze):
    x = prescribed(THETAS[0])
    rows = []
    for theta in THETAS:
        y = prescribed(theta)
        x, history, c = newton(surf, y, x, freeze)
        f = -c.residual(PENALTY, np.arange(3 * len(y)).reshape(-1, 3)).reshape(-1, 3).sum(0)
        t = np.radians(theta)
        radial = f @ np.array([np.cos(t), np.sin(t), 0.0])
        tangential = f @ np.array([-np.sin(t), np.cos(t), 0.0])
        rows.append(dict(theta=theta, its=len(history) - 1, history=history,
                         converged=history[-1] <= TOL, radial=radial, tangential=tangential,
                         norm=float(np.linalg.norm(f)), gap=c.projection.gap.copy()))
    return rows


def main():
    t0 = time.perf_counter()
    nodes, faces = target()
    schemes = {
        "facet": (FacetSurface(nodes, faces), False),
        "diffuse": (DiffuseSurface(nodes, faces), False),
        "diffuse-frozen": (DiffuseSurface(nodes, faces), True),
        "diffuse-global": (DiffuseSurface(nodes, faces, frame="global"), False),
    }
    print(__doc__.split("\n\n")[0])
    print(f"k_s = {KS}, eps = {PENALTY}, depth = {DEPTH} mm, {len(ZS)} contactors at z = {ZS}, "
          f"theta = {THETAS[0]}..{THETAS[-1]} step {THETAS[1] - THETAS[0]} deg; "
          f"facet edges at {EDGES}; Newton tolerance |r| <= {TOL:.0e}")
    for name, (surf, _) in schemes.items():
        if isinstance(surf, DiffuseSurface):
            print(f"  {name}: frame {surf.frame}, basis {surf.basis}, weight {surf.weight}, "
                  f"support {surf.support} {surf.radius}")
    results = {}
    for name, (surf, freeze) in schemes.items():
        t = time.perf_counter()
        results[name] = sweep(name, surf, freeze)
        print(f"  {name}: sweep of {len(THETAS)} steps in {time.perf_counter() - t:.1f} s")

    print("\nNewton residual norms |k_s (x - y) + R_c| (a few steps):")
    for theta in SHOW_HISTORY:
        k = int(np.argmin(np.abs(THETAS - theta)))
        for name in results:
            row = results[name][k]
            lin, quad = rates(row["history"])
            print(f"  theta={row['theta']:6.2f} {name:15s} its={row['its']:2d}  "
                  + " ".join(f"{r:.1e}" for r in row["history"])
                  + ("   r_k+1/r_k^2: " + " ".join(f"{q:.1e}" for q in quad) if quad else ""))

    print("\nTotal contact force on the row, radial (out of the cylinder) and tangential "
          "(e_theta):")
    names = list(results)
    print("  theta  " + "  ".join(f"{n + ' Fr':>18s} {n + ' Ft':>18s}"
                                  for n in ("facet", "diffuse")))
    for k, theta in enumerate(THETAS):
        if k % 2 and not any(abs(theta - e) < 0.6 for e in EDGES):
            continue
        mark = " <- edge" if any(abs(theta - e) < 0.3 for e in EDGES) else ""
        print(f"  {theta:6.2f} " + "  ".join(
            f"{results[n][k]['radial']:18.6f} {results[n][k]['tangential']:18.6f}"
            for n in ("facet", "diffuse")) + mark)

    print("\nSummary over the slide (radial force: exact answer is the same at every theta, so "
          "no detrending; amplitude = (max - min) / mean):")
    print(f"  {'scheme':15s} {'mean Fr':>10s} {'ampl Fr':>10s} {'range Ft/mean Fr':>17s} "
          f"{'max |dFt| step':>15s} {'its total':>9s} {'mean':>5s} {'max':>4s} "
          f"{'max r+/r':>9s} {'max r+/r^2':>10s} {'all conv':>8s}")
    for name in names:
        rows = results[name]
        fr = np.array([r["radial"] for r in rows])
        ft = np.array([r["tangential"] for r in rows])
        its = np.array([r["its"] for r in rows])
        lin = [v for r in rows for v in rates(r["history"])[0]]
        quad = [v for r in rows for v in rates(r["history"])[1]]
        lin_s = f"{max(lin):9.1e}" if lin else f"{'-':>9s}"
        quad_s = f"{max(quad):10.1e}" if quad else f"{'-':>10s}"
        print(f"  {name:15s} {fr.mean():10.5f} {(fr.max() - fr.min()) / fr.mean():10.2e} "
              f"{(ft.max() - ft.min()) / fr.mean():17.2e} "
              f"{np.abs(np.diff(ft)).max() / fr.mean():15.2e} {its.sum():9d} {its.mean():5.2f} "
              f"{its.max():4d} {lin_s} {quad_s} {str(all(r['converged'] for r in rows)):>8s}")
    exact = len(ZS) * KS * DEPTH * PENALTY / (KS + PENALTY)
    print(f"  (smooth-cylinder estimate of Fr: n k_s depth eps/(k_s + eps) = {exact:.5f}; the "
          f"faceted surface's chords sit up to 0.048 mm inside the cylinder)")
    print("  (max r+/r, max r+/r^2: over the Newton steps near the solution, r_k < 0.1 k_s depth, "
          "r_k+1 above round-off; quadratic convergence keeps r+/r^2 bounded)")
    print(f"\ntotal time {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
