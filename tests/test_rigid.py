"""The rigid-target element (diffsurf_cli.element.rigid): the gap to one fixed smooth surface.

- Taylor tests of g, ∂g/∂x^c = ν and the 3x3 ∂²g/∂x^c² (test_element's `_taylor`: remainders
  falling as h² and h³, finite differences of g and ν) on a sphere (inside and outside), a
  cylinder of quads, a saddle in the global frame and sample_meshes/cylinder.msh;
- the compiled kernel against the numpy reference (tests/reference_rigid.py), statuses too;
- the node fits are the projection's own (each node's proximal point lies on its φ_j = 0);
- pairing independence: a contactor's answer is bitwise the same alone, in any batch, in any
  order, after other contactors; along a slide across many facets of the sample cylinder,
  the second difference of g is bounded (g is C²) where the projection's grows as the step
  falls (kinks in dg/ds);
- accuracy against the exact shapes, next to the facets' and the projection's; curvatures;
- thin plates (one sheet blended), targets far from the origin, R and K of the penalty.
"""
from __future__ import annotations

import numpy as np
import pytest

import reference_rigid
import reference_steps
from diffsurf_cli.element.rigid import RigidResult, RigidTarget
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.projection import BAD_POINT, FAILED, OFF_TARGET, OK, OPEN, OUTSIDE, PENETRATION
from diffsurf_cli.targets import read_surface
from diffsurf_cli.testing.shapes import Cylinder, Plane, Saddle, Sphere
from samples import CYLINDER
from test_element import _taylor


def _cylinder_surface(**options):
    """The bundled half cylinder as one DiffuseSurface (what a rigid target is built on)."""
    _, nodes, faces = read_surface(CYLINDER)
    return DiffuseSurface(nodes, faces, **options)

# --------------------------------------------------------------------------------------------
# scenes: (surface, contactors, node spacing)
# --------------------------------------------------------------------------------------------


def _sphere(offset):
    shape = Sphere(center=(0.2, -0.1, 0.3), radius=1.0)
    nodes, faces = shape.mesh(5)
    on = shape.sample_near(3, 0.0, rng=11)
    _, normal, _ = shape.closest(on)
    return DiffuseSurface(nodes, [faces]), on + offset * normal, shape.spacing(5)


def _sphere_inside():
    return _sphere(-0.06)


def _sphere_outside():
    return _sphere(0.06)


def _cylinder_quads():
    shape = Cylinder(radius=10.0, length=20.0, center=(32.5, 30.0, 2.5))
    nodes, quads = shape.mesh_quads(24)
    on = shape.sample_near(3, 0.0, rng=13, margin=6.0)
    _, normal, _ = shape.closest(on)
    return DiffuseSurface(nodes, [quads]), on - 0.5 * normal, shape.spacing(24)


def _saddle_global():
    shape = Saddle(a=0.5, size=1.0)
    nodes, faces = shape.mesh(10)
    on = shape.sample_near(3, 0.0, rng=12, margin=0.35)
    _, normal, _ = shape.closest(on)
    return DiffuseSurface(nodes, [faces], frame="global"), on - 0.04 * normal, 0.2


def _sample_cylinder():
    surface = _cylinder_surface()
    rng = np.random.default_rng(3)
    theta = rng.uniform(np.radians(200), np.radians(340), 3)
    radius = 10.0 + np.array([-0.4, 0.3, -0.8])
    z = rng.uniform(0.0, 5.0, 3)
    points = np.stack([32.5 + radius * np.cos(theta), 30.0 + radius * np.sin(theta), z], 1)
    return surface, points, float(np.median(surface.node_spacing))


SCENES = {"sphere-inside": _sphere_inside, "sphere-outside": _sphere_outside,
          "cylinder-quads": _cylinder_quads, "saddle-global": _saddle_global,
          "sample-cylinder": _sample_cylinder}


@pytest.mark.parametrize("scene", list(SCENES))
def test_taylor(scene):
    surface, points, h = SCENES[scene]()
    rigid = RigidTarget(surface)
    res = rigid.evaluate(points)
    expected = np.where(np.einsum("mi,mi->m", points - res.proximal_point, res.normal) > 0,
                        OPEN, PENETRATION)
    assert np.all(res.status == expected), res.status
    assert np.any(res.status == OPEN) == (scene in ("sphere-outside", "sample-cylinder"))
    rng = np.random.default_rng(sum(map(ord, scene)))
    for i in range(len(points)):
        M = res.hessian[i]
        assert np.allclose(M, M.T, rtol=0, atol=1e-14 * np.abs(M).max())
        assert np.linalg.norm(res.normal[i]) == pytest.approx(1.0, abs=1e-15)
        assert abs(M @ res.normal[i]).max() <= 1e-12 * np.abs(M).max()  # ν is a null vector

        def evaluate(v, expected=expected[i]):
            r = rigid.evaluate(v[None])
            if r.status[0] != expected:
                return None
            return r.gap[0], r.normal[0]

        _taylor(evaluate, points[i].copy(), res.gap[i], res.normal[i], M, h, rng,
                f"{scene}/#{i}")


@pytest.mark.parametrize("options", [{"basis": "cubic", "weight": "gauss"},
                                     {"basis": "linear", "weight": "singular"},
                                     {"support": "knn"}, {"recentre": True}])
def test_taylor_options(options):
    """Other bases, weights, supports: the blend of their node fits is as smooth."""
    shape = Sphere(center=(0.2, -0.1, 0.3), radius=1.0)
    nodes, faces = shape.mesh(5)
    on = shape.sample_near(2, 0.0, rng=17)
    _, normal, _ = shape.closest(on)
    points = on - 0.05 * normal
    rigid = RigidTarget(DiffuseSurface(nodes, [faces], **options))
    res = rigid.evaluate(points)
    assert np.all(res.status == PENETRATION), res.status
    rng = np.random.default_rng(len(str(options)))
    for i in range(len(points)):
        def evaluate(v):
            r = rigid.evaluate(v[None])
            return None if r.status[0] != PENETRATION else (r.gap[0], r.normal[0])

        _taylor(evaluate, points[i].copy(), res.gap[i], res.normal[i], res.hessian[i],
                shape.spacing(5), rng, f"{options}/#{i}")


def test_second_false_same_first_order():
    surface, points, _ = _sphere_inside()
    rigid = RigidTarget(surface)
    a, b = rigid.evaluate(points), rigid.evaluate(points, second=False)
    assert b.hessian is None
    for name in ("gap", "normal", "proximal_point", "curvature", "status", "reason"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


# --------------------------------------------------------------------------------------------
# the kernel against the numpy reference; the node fits against the projection
# --------------------------------------------------------------------------------------------


def _mixed_cloud(surface, m=400, seed=5):
    """Points around the sample cylinder: inside, outside, past its open ends and edges, far
    away, and one NaN."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(np.radians(170), np.radians(370), m)
    radius = 10.0 + rng.uniform(-1.5, 1.5, m)
    radius[-60:] = 10.0 + rng.choice([-7.0, -5.0, 6.0, 12.0], 60)  # beyond the blend's reach
    z = rng.uniform(-5.0, 10.0, m)
    points = np.stack([32.5 + radius * np.cos(theta), 30.0 + radius * np.sin(theta), z], 1)
    points[0] = (32.5, 20.0, 40.0)  # far past an open end: off the target
    points[1] = (np.nan, 0.0, 0.0)
    return points


def test_kernel_matches_reference():
    surface = _cylinder_surface()
    rigid = RigidTarget(surface)
    points = _mixed_cloud(surface)
    fast, slow = rigid.evaluate(points), reference_rigid.evaluate(rigid, points)
    counts = np.bincount(fast.status, minlength=5)
    assert counts[OPEN] > 50 and counts[PENETRATION] > 50 and counts[OUTSIDE] > 50, counts
    # the deep and far ones, searched from their faceted feet, are answered too
    seeded = np.bincount(fast.status[-60:], minlength=5)
    assert seeded[OPEN] > 10 and seeded[PENETRATION] > 10, seeded
    assert np.array_equal(fast.status, slow.status)
    assert np.array_equal(fast.reason, slow.reason)
    assert (fast.status[0], fast.reason[0]) == (OUTSIDE, OFF_TARGET)
    assert (fast.status[1], fast.reason[1]) == (FAILED, BAD_POINT)
    ok = fast.reason == OK
    assert np.all(np.isnan(fast.gap[~ok])) and np.all(np.isnan(fast.hessian[~ok]))
    assert np.all(np.isfinite(fast.hessian[ok]))
    scale = {"gap": 10.0, "proximal_point": 40.0, "normal": 1.0, "curvature": 0.1,
             "hessian": 0.1}
    for name, s in scale.items():
        a, b = getattr(fast, name)[ok], getattr(slow, name)[ok]
        assert np.abs(a - b).max() <= 1e-12 * s, name


@pytest.mark.parametrize("basis", ["linear", "quadratic", "cubic"])
@pytest.mark.parametrize("weight", ["wendland", "gauss", "singular"])
def test_node_fits_are_the_projections(basis, weight):
    """φ_j vanishes at the proximal point of node j's own projection (same frame, support,
    radius and α as the engine), and its normal there is the projection's."""
    surface = _cylinder_surface(basis=basis, weight=weight)
    assert surface.basis == basis and surface.weight == weight
    rigid = RigidTarget(surface)
    proj = surface.project(surface.nodes[rigid.node])
    Z = np.einsum("mij,mj->mi", rigid.axes,
                  proj.proximal_point - rigid.origin) / rigid.radius[:, None]
    p = [reference_steps.basis(surface.basis, Z[:, 0], Z[:, 1], *d)
         for d in ((0, 0), (1, 0), (0, 1))]
    f, fs, ft = (np.einsum("mk,mk->m", q, rigid.alpha) for q in p)
    assert np.abs(rigid.radius * (Z[:, 2] - f)).max() <= 1e-12 * rigid.radius.max()
    nu = np.einsum("mji,mj->mi", rigid.axes, np.stack([-fs, -ft, np.ones_like(f)], 1))
    nu /= np.linalg.norm(nu, axis=1)[:, None]
    assert np.abs(nu - proj.normal).max() <= 1e-10


# --------------------------------------------------------------------------------------------
# pairing independence
# --------------------------------------------------------------------------------------------


def _same(a: RigidResult, b: RigidResult, rows_a, rows_b):
    for name in ("gap", "normal", "proximal_point", "hessian", "curvature", "status",
                 "reason", "iterations"):
        x, y = getattr(a, name)[rows_a], getattr(b, name)[rows_b]
        assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name


def test_answer_depends_on_the_contactor_alone():
    surface = _cylinder_surface()
    rigid = RigidTarget(surface)
    points = _mixed_cloud(surface, m=300, seed=8)
    whole = rigid.evaluate(points)
    # alone, one at a time
    for i in range(0, 300, 37):
        _same(whole, rigid.evaluate(points[i:i + 1]), [i], [0])
    # shuffled, and among other contactors (nearby ones first)
    order = np.random.default_rng(1).permutation(300)
    _same(whole, rigid.evaluate(points[order]), order, np.arange(300))
    nearby = points + 0.05
    rigid.evaluate(nearby)
    mixed = rigid.evaluate(np.vstack([nearby, points]))
    _same(whole, mixed, np.arange(300), np.arange(300, 600))
    # a new RigidTarget of the same surface, and the cached one
    _same(whole, RigidTarget(surface).evaluate(points), np.arange(300), np.arange(300))
    assert RigidTarget.for_surface(surface) is RigidTarget.for_surface(surface)
    other = _cylinder_surface()
    assert RigidTarget.for_surface(other) is not RigidTarget.for_surface(surface)


def _slide(n):
    """A slide across many facets of the sample cylinder: 140° around, 5 mm along the axis,
    from 0.3 mm inside to 0.1 mm outside."""
    theta = np.linspace(np.radians(200), np.radians(340), n)
    radius = 10.0 - 0.3 + 0.4 * np.linspace(0.0, 1.0, n)
    z = np.linspace(0.0, 5.0, n)
    points = np.stack([32.5 + radius * np.cos(theta), 30.0 + radius * np.sin(theta), z], 1)
    ds = np.linalg.norm(np.diff(points, axis=0), axis=1).mean()
    return points, ds


def _second_difference(gap, ds):
    assert np.all(np.isfinite(gap))
    return np.abs(np.diff(gap, 2)).max() / ds**2


def test_slide_has_continuous_slope():
    """g is C² along the slide: max |Δ²g|/ds² (≈ max |g''|) is the same at two step sizes.
    The projection's gap (a fit around each contactor) has kinks where its support or frame
    changes: a jump J in dg/ds makes |Δ²g|/ds² ≈ J/ds, growing as the step falls (measured:
    rigid 2.146e-3 at both steps; projection 5.3e-3 then 9.5e-3, 6.6e-2 at a step 10x finer
    again)."""
    surface = _cylinder_surface()
    rigid = RigidTarget(surface)
    coarse, ds_coarse = _slide(4001)
    fine, ds_fine = _slide(40001)
    rigid_coarse = _second_difference(rigid.evaluate(coarse).gap, ds_coarse)
    rigid_fine = _second_difference(rigid.evaluate(fine).gap, ds_fine)
    proj_coarse = _second_difference(surface.project(coarse).gap, ds_coarse)
    proj_fine = _second_difference(surface.project(fine).gap, ds_fine)
    assert rigid_fine <= 1.1 * rigid_coarse, (rigid_coarse, rigid_fine)
    assert proj_fine >= 1.5 * proj_coarse, (proj_coarse, proj_fine)  # the check can fail
    # and the slope itself: dg/ds within the range of the exact cylinder's ± the curvature
    # error of a coarse mesh (h = 2.2 mm on R = 10 mm)
    g = rigid.evaluate(fine).gap
    exact = np.hypot(fine[:, 0] - 32.5, fine[:, 1] - 30.0) - 10.0
    assert np.abs(g - exact).max() < 0.02


# --------------------------------------------------------------------------------------------
# accuracy and curvature against the exact shapes
# --------------------------------------------------------------------------------------------


def _errors(shape, nodes, faces, points, **options):
    _, _, exact = shape.closest(points)
    surface = DiffuseSurface(nodes, faces, **options)
    rigid = RigidTarget(surface).evaluate(points)
    proj = surface.project(points)
    facet = FacetSurface(nodes, faces).project(points)
    assert np.all(rigid.reason == OK) and np.all(proj.reason == OK)
    return (np.abs(rigid.gap - exact).max(), np.abs(proj.gap - exact).max(),
            np.abs(facet.gap - exact).max(), rigid)


@pytest.mark.parametrize("case", ["sphere", "cylinder"])
def test_accuracy(case):
    """Gap error far below the facets' and comparable to the projection's (max errors,
    measured: sphere 0.0026 and 0.31 of them, cylinder of quads 0.013 and 0.32)."""
    if case == "sphere":
        shape = Sphere(radius=1.0)
        nodes, faces = shape.mesh(10)
        h = shape.spacing(10)
        points = shape.sample_near(2000, 0.3 * h, rng=2)
    else:
        shape = Cylinder(radius=10.0, length=20.0)
        nodes, faces = shape.mesh_quads(24)
        h = shape.spacing(24)
        points = shape.sample_near(2000, 0.3 * h, rng=2, margin=3 * h)
    rigid, proj, facet, _ = _errors(shape, nodes, [faces], points)
    assert rigid < 0.02 * facet, (rigid, proj, facet)
    assert rigid < 2.0 * proj, (rigid, proj, facet)


def test_curvature():
    """Principal curvatures of S against the exact ones (sphere 1/R, 1/R; cylinder 1/R, 0),
    converging as the mesh is refined."""
    errors = []
    for n in (6, 12):
        shape = Sphere(radius=2.0)
        nodes, faces = shape.mesh(n)
        points = shape.sample_near(300, 0.2 * shape.spacing(n), rng=4)
        r = RigidTarget(DiffuseSurface(nodes, [faces])).evaluate(points)
        assert np.all(r.status != FAILED)
        errors.append(np.abs(r.curvature - 0.5).max() * 2.0)  # relative to 1/R
    assert errors[0] < 0.1 and errors[1] < 0.35 * errors[0], errors
    shape = Cylinder(radius=10.0, length=20.0)
    nodes, quads = shape.mesh_quads(32)
    points = shape.sample_near(300, 0.5, rng=5, margin=4.0)
    r = RigidTarget(DiffuseSurface(nodes, [quads])).evaluate(points)
    assert np.all(r.reason == OK)
    assert np.abs(r.curvature[:, 0] - 0.1).max() < 0.01 * 0.1 * 10
    assert np.abs(r.curvature[:, 1]).max() < 0.01 * 0.1 * 10
    # the Hessian of g is Σ κ_i / (1 + g κ_i) t_i t_iᵀ: on the cylinder, 1 / (R + g) along
    # the circumference
    _, _, exact = shape.closest(points)
    top = np.linalg.eigvalsh(r.hessian)[:, -1]
    assert np.abs(top * (10.0 + exact) - 1.0).max() < 0.01 * 10


def test_thin_plate_blends_one_sheet():
    """Two sheets half a spacing apart (a thin plate, both faces meshed): each contactor's
    surface is its own side's (the far face's frames face away), so the gaps are exact on
    these planes; blending both faces shifted them by 3% of a spacing at a whole spacing
    apart, before the sheet test."""
    h = 0.1
    top = Plane(origin=(0, 0, 0.5 * h), normal=(0, 0, 1), size=1.0)
    bottom = Plane(origin=(0, 0, 0), normal=(0, 0, -1), size=1.0)
    (n1, q1), (n2, q2) = top.mesh_quads(20), bottom.mesh_quads(20)
    surface = DiffuseSurface(np.vstack([n1, n2]), [np.vstack([q1, q2 + len(n1)])])
    rigid = RigidTarget(surface)
    xy = np.random.default_rng(0).uniform(-0.6, 0.6, (100, 2))
    for z, gap, status in ((0.8 * h, 0.3 * h, OPEN), (0.4 * h, -0.1 * h, PENETRATION),
                           (-0.2 * h, 0.2 * h, OPEN)):
        r = rigid.evaluate(np.column_stack([xy, np.full(100, z)]))
        assert np.all(r.status == status)
        assert np.abs(r.gap - gap).max() < 1e-12
        assert np.abs(r.curvature).max() < 1e-9


@pytest.mark.parametrize("shift", [1e3, 1e5, 1e7])
def test_far_from_the_origin(shift):
    """The kernel works relative to the contactor: the same scene translated far from the
    origin (1e7 mm: 4.5e6 node spacings) gives the same answers to round-off of the
    coordinates (ε |x|), where Newton in absolute coordinates stalled from 1e4 on."""
    surface = _cylinder_surface()
    points, _ = _slide(200)
    near = RigidTarget(surface).evaluate(points)
    moved = DiffuseSurface(surface.nodes + shift, surface.faces)
    far = RigidTarget(moved).evaluate(points + shift)
    assert np.array_equal(far.status, near.status)
    rounding = 64 * np.finfo(float).eps * shift
    assert np.abs(far.gap - near.gap).max() <= rounding
    assert np.abs(far.proximal_point - shift - near.proximal_point).max() <= rounding
    assert np.abs(far.normal - near.normal).max() <= rounding / 2.0
    assert np.abs(far.hessian - near.hessian).max() <= rounding / 2.0


def test_residual_and_tangent_are_the_penalty_energys_derivatives():
    """R = ε g ν and K = ε (g ∂²g/∂x² + ννᵀ) are the gradient and Hessian of ε g²/2 (central
    differences of the energy and of R, per contactor, with per-contactor penalties)."""
    surface, points, h = _sample_cylinder()
    rigid = RigidTarget(surface)
    res = rigid.evaluate(points)
    eps = np.array([1e3, 2e3, 5e2])
    R, K = res.residual(eps), res.tangent(eps)
    assert R.shape == (3, 3) and K.shape == (3, 3, 3)
    step = 1e-5 * h
    for i in range(3):
        for k in range(3):
            d = np.zeros(3)
            d[k] = step
            plus, minus = rigid.evaluate([points[i] + d]), rigid.evaluate([points[i] - d])
            fd = eps[i] * (plus.gap[0] ** 2 - minus.gap[0] ** 2) / 2 / (2 * step)
            assert fd == pytest.approx(R[i, k], rel=1e-7, abs=1e-9 * eps[i])
            dR = (plus.residual(eps[i])[0] - minus.residual(eps[i])[0]) / (2 * step)
            assert np.allclose(dR, K[i, :, k], rtol=1e-6, atol=1e-8 * eps[i])
    with pytest.raises(ValueError, match="second=True"):
        rigid.evaluate(points, second=False).tangent(1.0)
