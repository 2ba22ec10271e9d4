"""The paper's example (examples/plate_on_cylinder.py, issue 12 item 5), its --quick run in-process:
every Newton step converges, Newton is quadratic for a smooth law, the PNG is written, and the
diffuse element's contact force is closer to the exact cylinder's than node-to-facet's."""
from __future__ import annotations

import io

import numpy as np
import pytest

from samples import load_example

pytest.importorskip("skfem")
pytest.importorskip("matplotlib")


# r_{k+1} / r_k^2 of the relative residual once the active set is fixed. Quadratic Newton keeps
# it near the law's second-derivative constant (the exact cylinder: below 1); linear convergence
# at rate q gives q / r_k, which grows without bound as r_k falls (1e2 and more at r_k ~ 1e-6).
BOUND = 10.0


def _load():
    return load_example("plate_on_cylinder")


@pytest.fixture(scope="module")
def example():
    return _load()


@pytest.fixture(scope="module")
def quick(example, tmp_path_factory):
    png = tmp_path_factory.mktemp("example") / "plate.png"
    out = io.StringIO()
    res = example.run(quick=True, png=str(png), out=out)
    res["png"] = png
    res["table"] = out.getvalue()
    return res


@pytest.mark.slow
def test_every_step_converges(quick):
    for name, hist in quick["results"].items():
        assert len(hist) == len(quick["results"]["exact"])
        assert all(s.converged for s in hist), name
        # and something was pressed: every step has contactors in contact
        assert all(s.active[-1] > 0 for s in hist), name
        assert all(-s.force[1] > 0 for s in hist), name


def _check_quadratic(example, quick, name):
    hist = quick["results"][name]
    measured = 0
    for s in hist:
        ratios = s.ratios(example.FLOOR)
        measured += len(ratios)
        assert all(q <= BOUND for q in ratios), (name, s.drive, s.residuals)
    # enough ratios were taken for the bound to mean something
    assert measured >= len(hist) // 2


def test_newton_quadratic_exact_cylinder(example, quick):
    _check_quadratic(example, quick, "exact")


def test_newton_quadratic_diffuse(example, quick):
    _check_quadratic(example, quick, "diffuse")


def test_png_written(quick):
    data = quick["png"].read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(data) > 20_000  # three panels of curves, not an empty canvas


def test_diffuse_force_closer_to_exact_than_facet(quick):
    res = quick["results"]
    F = {name: np.array([s.force for s in hist]) for name, hist in res.items()}
    dev = {name: np.abs(F[name] - F["exact"]).max(axis=0) for name in ("diffuse", "facet")}
    # normal (y) and tangential (x) total force, worst step: diffuse an order of magnitude closer
    assert dev["diffuse"][1] < 0.1 * dev["facet"][1]
    assert dev["diffuse"][0] < 0.1 * dev["facet"][0]
    s = quick["summary"]
    assert s["diffuse"]["dFn"] < s["facet"]["dFn"] and s["diffuse"]["dp"] < s["facet"]["dp"]
    assert "Newton iterations per step, diffuse" in quick["table"]


def test_exact_law_taylor(example):
    """The reference law's N and M are the gradient and Hessian of its gap: the second-order
    Taylor remainder falls as h^3."""
    rng = np.random.default_rng(3)
    x = np.column_stack([rng.uniform(30, 35, 20), rng.uniform(20.5, 21, 20),
                         rng.uniform(0, 5, 20)])
    _, g, N, M = example.exact_law(x)
    assert len(g) == len(x)
    d = rng.normal(size=x.shape)
    rem = []
    for h in (1e-2, 5e-3, 2.5e-3):
        idx, gh, _, _ = example.exact_law(x + h * d)
        assert len(idx) == len(x)
        pred = (g + h * np.einsum("ij,ij->i", N, d)
                + 0.5 * h * h * np.einsum("ij,ijk,ik->i", d, M, d))
        rem.append(np.abs(gh - pred).max())
    assert rem[0] / rem[1] > 7 and rem[1] / rem[2] > 7  # 8 for h^3


def test_condensed_solve_is_the_full_solve(example, quick):
    """Newton's static condensation on the top face gives the same step as a sparse solve of
    the whole system (K + K_c) du = -r on the free DOFs."""
    import scipy.sparse.linalg as spla

    plate = quick["plate"]
    rng = np.random.default_rng(5)
    u = np.zeros(plate.n_dofs)
    u[plate.dofs[:, 1]] = 0.3  # the plate lifted: its top-face contactors in the cylinder
    u[plate.free] += 1e-3 * rng.normal(size=len(plate.free))
    index, _, R, Kt, _ = example.contact_terms(plate, example.exact_law, u, quick["penalty"])
    assert len(index) > 0
    r = plate.K @ u + R
    du = plate.solver.solve(Kt, r)
    free = plate.free
    ref = spla.spsolve((plate.K + Kt)[free][:, free].tocsc(), -r[free])
    assert np.abs(du[free] - ref).max() <= 1e-9 * np.abs(ref).max()
    assert not np.any(du[plate.fixed.ravel()])
