"""The support floor over quads (`patches.surface.support_floor`, issue 19 item 2): the patched
pass widens a patch's support over elongated quads to at least a fraction of the quad's
longest edge. The contact element takes that same support (`DiffuseSurface.project`'s
`h_min`), and a second-order quad, a node every half edge, takes half of it."""
import numpy as np
import pytest

from diffsurf_cli import contact
from diffsurf_cli.targets import build_surface, read_surface


def _cylinder(around, heights, radius=1.0):
    """A cylinder of first-order quads: `around` sections, rings at `heights`."""
    th = np.linspace(0, 2 * np.pi, around, endpoint=False)
    nodes = np.array([[radius * np.cos(t), radius * np.sin(t), z] for z in heights for t in th])
    quads = [[j * around + i, j * around + (i + 1) % around,
              (j + 1) * around + (i + 1) % around, (j + 1) * around + i]
             for j in range(len(heights) - 1) for i in range(around)]
    return nodes, np.array(quads)


def _near_cylinder(m, lo, hi, seed=0):
    rng = np.random.default_rng(seed)
    th, z, r = rng.uniform(0, 2 * np.pi, m), rng.uniform(lo, hi, m), rng.uniform(0.97, 1.03, m)
    return np.c_[r * np.cos(th), r * np.sin(th), z]


def test_element_gap_is_the_projections_over_elongated_quads():
    """Quads 0.1 around, 0.5 along: the floor widens the supports. The element's gap, normal
    and proximal point are the projection's (before: the element searched again without the
    floor, and its gap was up to 0.054 off the projection's, where the answers are 1e-3)."""
    heights = np.arange(0.0, 10.01, 0.5)
    nodes, quads = _cylinder(60, heights)
    surface = build_surface(nodes, [quads])
    assert (surface.support_floor > surface.node_spacing.max()).all()
    x = _near_cylinder(3000, heights[1], heights[-2])
    proj = surface.project(x)
    assert (proj.source == 0).all()
    near = np.flatnonzero(np.abs(proj.gap) < 0.05)
    c = contact(surface, x[near])
    rows = near[c.contactor]
    assert len(rows) > 1000
    np.testing.assert_allclose(c.gap, proj.gap[rows], rtol=0, atol=1e-11)
    np.testing.assert_allclose(c.projection.proximal_point[c.contactor],
                               proj.proximal_point[rows], rtol=0, atol=1e-10)


@pytest.mark.parametrize("incomplete", [False, True])
def test_second_order_quads_take_half_the_floor(tmp_path, incomplete):
    """A gmsh sphere of quad9 (quad8) cells: their nodes are half an edge apart, so the floor
    is half a first-order quad's; the patched surface answers as its patch's own surface
    (before: 0.55 of the whole edge, twice the nodes' spacing, RMS 3.5e-3 against 5.1e-4)."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.sphere_surface(tmp_path / "s.msh", size=np.pi / 6, order=2, quads=True,
                                      incomplete=incomplete)
    _, nodes, faces = read_surface(path)
    surface = build_surface(nodes, faces)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    x = d * rng.uniform(0.97, 1.03, (4000, 1))
    exact = np.linalg.norm(x, axis=1) - 1.0
    rms = lambda g: float(np.sqrt(np.mean((g - exact) ** 2)))  # noqa: E731
    patched, own = surface.project(x).gap, surface.surfaces[0].project(x).gap
    assert rms(patched) <= 1.01 * rms(own)
