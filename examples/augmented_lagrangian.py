"""An augmented Lagrangian with the contact element's API (issue 33): the penetration driven to
round-off in a few augmentations, with the penalty you have.

Uzawa's loop after Alart-Curnier: each augmentation solves the equilibrium by Newton with the
multipliers λ of the last one (`c.residual(eps, ..., multipliers=lam)`, `c.tangent(...,
multipliers=lam)`: each contactor's normal force p = min(0, λ + ε g)), then updates them
(`lam = c.multipliers(eps, lam)`: λ ← min(0, λ + ε g)). A contactor slightly open with
λ + ε g < 0 still carries a force: `contact(..., near=Contact.reach(eps, lam))` gives it its
element.

Two scenes, springs standing in for the bodies' stiffness (no FE code needed):

- rigid: 8 contactors on springs (stiffness 1) pulled 0.5 mm into the bundled cylinder, a
  rigid target (`rigid_target=True`), penalty 30: the penalty alone leaves about 0.5 / 31;
- deformable: 9 contactors on springs pulled 0.2 into a sphere of radius 10 (the default
  `PatchedSurface` of `testing.shapes.Sphere`'s mesh) whose nodes sit on springs (stiffness
  10) to their rest positions: the full element, coupling contactor and target DOFs, the
  pairing held fixed where the loop starts (`Contact.pairing`), penalty 30.

Each augmentation divides the penetration by about 1 + ε / k (k the springs' stiffness):
about 6 augmentations to 1e-11 here. Newton stops, unconverged, if a contactor is lost or
fails (`c.lost`, `c.status`: docs/solver.md).

    python examples/augmented_lagrangian.py        # a second or two
"""
from __future__ import annotations

import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

EPS = 30.0          # the penalty ε per contactor
SPRING = 1.0        # each contactor's spring to where it is pulled
TARGET_SPRING = 10.0 # each target node's spring to its rest position (the deformable scene)
TOL = 1e-12         # Newton's residual tolerance (force)
DONE = 1e-11        # the penetration the loop stops at (round-off: 1e-12 of the scene's size)


def cylinder_scene():
    """(surface, pulled-to points) of the rigid scene."""
    from diffsurf_cli import DiffuseSurface, read_target
    from diffsurf_cli.mls.frame import corner_faces

    target = read_target("sample_meshes/cylinder.msh")
    nodes = target.points[target.nodes]
    faces = [np.searchsorted(target.nodes, f) for f in corner_faces(target.cells)]
    t = np.radians(np.linspace(250, 290, 8))  # axis along z through x = 32.5, y = 30
    y = np.column_stack([32.5 + 9.5 * np.cos(t), 30 + 9.5 * np.sin(t), np.full(8, 2.5)])
    return DiffuseSurface(nodes, faces), y


def sphere_scene():
    """(surface, pulled-to points) of the deformable scene: 9 points 0.2 inside the top."""
    from diffsurf_cli import PatchedSurface
    from diffsurf_cli.testing.shapes import Sphere

    nodes, faces = Sphere(radius=10.0).mesh(12)
    a = np.radians(np.linspace(-6.0, 6.0, 3))
    A, B = np.meshgrid(a, a)
    d = np.column_stack([np.sin(A.ravel()), np.sin(B.ravel()), np.ones(9)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return PatchedSurface(nodes, [faces]), 9.8 * d


def augmented(surface, y, rigid: bool, augmentations: int = 10, out=sys.stdout) -> dict:
    """Uzawa's loop on one scene; returns the largest penetration after each augmentation's
    Newton solve, the Newton iterations of each, and the final multipliers."""
    from diffsurf_cli import Contact, contact
    from diffsurf_cli.projection import FAILED

    m = len(y)
    n = 0 if rigid else len(surface.nodes)
    rest = np.asarray(surface.nodes, dtype=np.float64)[:n]  # the target's DOFs (none: rigid)
    cd = np.arange(3 * m).reshape(m, 3)
    td = None if rigid else 3 * m + np.arange(3 * n).reshape(n, 3)
    size = 3 * (m + n)
    stiffness = sp.diags(np.concatenate([np.full(3 * m, SPRING), np.full(3 * n, TARGET_SPRING)]))
    x, z = y.copy(), rest.copy()
    pairing = None if rigid else contact(surface, x, second=False).pairing
    lam = np.zeros(m)
    penetration, iterations = [], []
    for k in range(augmentations):
        near = Contact.reach(EPS, lam)  # every contactor that can carry a force has an element
        for it in range(30):  # noqa: B007  (its count is reported)
            target = surface if rigid else surface.moved(z)
            c = contact(target, x, rigid_target=rigid, pairing=pairing, near=near)
            if len(c.lost) or (c.status == FAILED).any():  # no answer: a force may be missing
                print(f"  augmentation {k}: {len(c.lost)} contactors lost, "
                      f"{(c.status == FAILED).sum()} failed: stopped", file=out)
                return {"penetration": penetration, "iterations": iterations,
                        "multipliers": lam, "converged": False}
            u = np.concatenate([(x - y).ravel(), (z - rest).ravel()])
            r = stiffness @ u + c.residual(EPS, cd, td, size, multipliers=lam)
            if np.abs(r).max() <= TOL:
                break
            K = stiffness + c.tangent(EPS, cd, td, size, multipliers=lam)
            du = spla.spsolve(K.tocsc(), r)
            x = x - du[:3 * m].reshape(m, 3)
            z = z - du[3 * m:].reshape(n, 3)
        iterations.append(it)
        penetration.append(max(0.0, -np.nanmin(c.projection.gap)))
        force = c.tractions(EPS, lam).normal
        print(f"  augmentation {k}: Newton {it} iterations, largest penetration "
              f"{penetration[-1]:.1e}, contact force {force.sum():.6f}", file=out)
        if penetration[-1] <= DONE:
            break
        lam = c.multipliers(EPS, lam)
    return {"penetration": penetration, "iterations": iterations, "multipliers": lam,
            "converged": np.abs(r).max() <= TOL}


def run(out=sys.stdout) -> dict:
    res = {}
    print("rigid target (the bundled cylinder):", file=out)
    res["rigid"] = augmented(*cylinder_scene(), rigid=True, out=out)
    print("deformable target (a sphere on springs, the full element):", file=out)
    res["deformable"] = augmented(*sphere_scene(), rigid=False, out=out)
    return res


def main() -> int:
    res = run()
    return 0 if all(r["converged"] and r["penetration"][-1] <= DONE
                    for r in res.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
