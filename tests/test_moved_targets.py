"""A deformable target (`PatchedSurface.moved`) whose reference mesh holds nodes that add no
geometry (issue 34's refinement rule, `segment.geometry_free`): those nodes are left out of the
reference surface's fit, but once the target deforms each node's displacement is its own, so
the moved surface is fitted over every node (`PatchedSurface._deformable_fits`). Before, a
moved target ignored them: a contactor pressing on one gave it no force, and moving it did not
move the surface."""
import numpy as np
import trimesh

from diffsurf_cli import contact
from diffsurf_cli.targets import build_surface


def _refined_sphere():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    nodes, faces = trimesh.remesh.subdivide(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    return nodes, faces, len(mesh.vertices)  # nodes past the first n0 add no geometry


def test_moved_target_gives_force_to_nodes_that_add_no_geometry():
    nodes, faces, n0 = _refined_sphere()
    surface = build_surface(nodes, [faces])
    assert surface.geometry_free == len(nodes) - n0
    k = n0 + 7  # a node on a chord of the coarse mesh
    x = 0.98 * nodes[k][None]  # a contactor just inside the sphere, over it
    moved = surface.moved(nodes)
    c = contact(moved, x)
    assert len(c.contactor) == 1
    R = c.residual(1.0, np.arange(3)[None], 3 + np.arange(3 * len(nodes)).reshape(-1, 3),
                   3 + 3 * len(nodes))
    force = np.linalg.norm(R[3:].reshape(-1, 3), axis=1)
    # the node under the contactor carries a share of its force as its neighbours do
    assert force[k] > 0.05 * force.max()


def _sphere_points(n=3000):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    x = d * rng.uniform(0.95, 1.05, (n, 1))
    return x, np.linalg.norm(x, axis=1) - 1.0  # the exact gap to the unit sphere


def test_moved_target_at_the_reference_is_the_reference_surface():
    """The nodes that add no geometry are lifted onto the reference surface before the moved
    fit takes them: at the reference positions the moved target is as accurate as the
    reference surface (fitted over the chords' nodes as they are, it would be 17x worse:
    issue 34's linear refinement)."""
    nodes, faces, _ = _refined_sphere()
    surface = build_surface(nodes, [faces])
    x, exact = _sphere_points()
    ref = surface.project(x).gap
    moved = surface.moved(nodes).project(x).gap
    rms = lambda g: float(np.sqrt(np.mean((g - exact) ** 2)))  # noqa: E731
    assert rms(moved) <= 1.2 * rms(ref)
    assert np.max(np.abs(moved - ref)) < 1e-3


def test_moving_a_node_that_adds_no_geometry_moves_the_surface():
    nodes, faces, n0 = _refined_sphere()
    surface = build_surface(nodes, [faces])
    k = n0 + 7
    x = 0.98 * nodes[k][None]
    before = surface.moved(nodes).project(x).gap[0]
    dented = nodes.copy()
    dented[k] *= 0.97  # pushed in past the contactor
    after = surface.moved(dented).project(x).gap[0]
    assert after - before >= 0.8 * 0.03 * np.linalg.norm(nodes[k])
