"""The guard is written once (issue 31): the compiled rule `_pass.guard_holds` is what the
projection runs and what the rigid element asks through `PatchedSurface.within_guard`. Checked
against the numpy rule it replaced (tests/reference_guard_rule.py), bit for bit, on targets
with creases, flipped, with the guard off, with plane fits (which the numpy copy let pass)."""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.testing.shapes import Cylinder, Sphere
from reference_guard_rule import within_guard as reference


def _surfaces():
    nodes, faces = Sphere().mesh(4)
    cyl_nodes, cyl_faces = Cylinder(radius=1.0, length=2.0).mesh_quads(12)
    return {
        "sphere": PatchedSurface(nodes, [faces]),
        "sphere flipped": PatchedSurface(nodes, [faces], flip=True),
        "sphere unguarded": PatchedSurface(nodes, [faces], guard=False),
        "cylinder quads": PatchedSurface(cyl_nodes, [cyl_faces]),
    }


@pytest.fixture(scope="module", params=list(_surfaces()))
def surface(request):
    return _surfaces()[request.param]


def _answers(surf, m, rng):
    """Answers around the guard's bounds: gaps within and past each facet's sag band,
    normals from the facet's own to 60 degrees off, feet up to a spacing apart, some rows
    without a faceted answer, some plane fits."""
    F = len(surf.facet_normal)
    facet = rng.integers(0, F, m)
    facet[rng.random(m) < 0.05] = -1
    f = np.maximum(facet, 0)
    facet_gap = rng.normal(scale=0.05, size=m)
    band = surf.gap_hi[f] - surf.gap_lo[f]
    gap = facet_gap + surf.gap_lo[f] + rng.uniform(-0.5, 1.5, m) * band
    sign = -1.0 if surf.flip else 1.0
    tilt = rng.normal(size=(m, 3)) * rng.uniform(0, 1.0, (m, 1))
    normal = sign * surf.facet_normal[f] + tilt
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    apart = rng.uniform(0, 1, m) * np.median(surf.node_spacing)
    plane = rng.random(m) < 0.1
    return gap, normal, facet, facet_gap, apart, plane


def test_the_compiled_guard_is_the_numpy_rule_bit_for_bit(surface):
    rng = np.random.default_rng(3)
    gap, normal, facet, facet_gap, apart, plane = _answers(surface, 20000, rng)
    for flags in (None, plane):
        got = surface.within_guard(gap, normal, facet, facet_gap, apart, flags)
        want = reference(surface, gap, normal, facet, facet_gap, apart, flags)
        assert got.dtype == bool
        np.testing.assert_array_equal(got, want)
    if surface.guard:  # both outcomes occur: the comparison can fail
        got = surface.within_guard(gap, normal, facet, facet_gap, apart)
        assert 0.05 < got.mean() < 0.95


def test_a_plane_fit_fails_the_guard_wherever_the_guard_is_on(surface):
    rng = np.random.default_rng(4)
    gap, normal, facet, facet_gap, apart, _ = _answers(surface, 500, rng)
    got = surface.within_guard(gap, normal, facet, facet_gap, apart, np.ones(500, bool))
    expect = (facet < 0) | (not surface.guard)
    np.testing.assert_array_equal(got, expect)


def test_bad_arrays_are_refused_in_one_line(surface):
    with pytest.raises(ValueError, match="lengths differ"):
        surface.within_guard(np.zeros(3), np.zeros((2, 3)), np.zeros(3, int), np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="facet"):
        surface.within_guard(np.zeros(1), np.zeros((1, 3)), np.array([10 ** 9]), np.zeros(1),
                             0.0)


def test_past_an_open_edge_the_projection_and_the_rigid_element_agree():
    """A contactor that overhangs a flat plate's open edge a little: the facets' gap is the
    distance to the edge, which no smoothing explains, so the guard measures the diffuse gap
    from the foot facet's plane (`_pass.facet_height`), in the projection and in the rigid
    element alike (before: the rigid element's guard took the edge's distance, -0.010 where
    the projection said -0.001)."""
    from diffsurf_cli import contact
    from diffsurf_cli.targets import build_surface

    g = np.linspace(0.0, 1.0, 5)
    X, Y = np.meshgrid(g, g, indexing="ij")
    nodes = np.c_[X.ravel(), Y.ravel(), np.zeros(25)]
    idx = np.arange(25).reshape(5, 5)
    quads = np.c_[idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(),
                  idx[:-1, 1:].ravel()]
    plate = build_surface(nodes, [quads])
    x = np.array([[1.01, 0.5, -1e-3], [0.5, 0.5, -1e-3], [1.004, 0.3, -2e-3]])
    proj = plate.project(x)
    np.testing.assert_allclose(proj.gap, x[:, 2], atol=1e-12)  # the height under the plate
    # what the guard measured from, declared for the element (no second search): the height,
    # where the facets' own gap past the edge is the distance to it
    np.testing.assert_allclose(proj.guard_gap, x[:, 2], atol=1e-12)
    assert proj.facet_gap[0] == pytest.approx(-np.hypot(0.01, 1e-3), abs=1e-12)
    for rigid in (False, True):
        c = contact(plate, x, rigid_target=rigid)
        np.testing.assert_array_equal(c.contactor, [0, 1, 2])
        np.testing.assert_allclose(c.gap, proj.gap, atol=1e-12)
