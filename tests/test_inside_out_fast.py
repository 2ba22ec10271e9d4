"""The winding check's closed edges from one compiled pass (`patches._edges.closed_pairs`,
issue 36) are numpy's former masks and gathers, and `projection.inside_out` answers as the
former code (tests/reference_inside_out.py), bit for bit: on closed spheres wound either way,
a sphere with a facet flipped (an edge run the same way twice), open and non-manifold
surfaces, a cavity, several bodies, quad and mixed blocks, second-order cells, a seam of
coincident nodes."""
from __future__ import annotations

import numpy as np
import pytest

import reference_inside_out as ref
from diffsurf_cli.patches import _edges
from diffsurf_cli.patches import segment as _segment
from diffsurf_cli.projection import inside_out
from diffsurf_cli.testing.shapes import Torus


def _sphere(sub=2, r=1.0, c=(0.0, 0.0, 0.0)):
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.asarray(m.vertices) * r + np.asarray(c), np.asarray(m.faces)


def _merge(*parts):
    nodes, faces, off = [], [], 0
    for x, f in parts:
        nodes.append(x)
        faces.append(f + off)
        off += len(x)
    return np.concatenate(nodes), np.concatenate(faces)


def _cases():
    x, f = _sphere()
    yield "sphere", x, [f]
    yield "inside out", x, [f[:, ::-1]]
    g = f.copy()
    g[5] = g[5, ::-1]
    yield "one facet flipped", x, [g]
    keep = x[f].mean(axis=1)[:, 2] > 0.2
    yield "open", x, [f[keep]]
    yield "non-manifold", x, [np.concatenate([f, f[:3], f[7:9, ::-1]])]
    outer, inner = _sphere(2, 2.0), _sphere(1, 0.5)
    yield "cavity", *(lambda n, ff: (n, [ff]))(*_merge(outer, (inner[0], inner[1][:, ::-1])))
    a, b, c = _sphere(1, 1.0, (3, 0, 0)), _sphere(2, 0.7), _sphere(1, 0.4, (0, 4, 0))
    yield "bodies", *(lambda n, ff: (n, [ff]))(*_merge(a, (b[0], b[1][:, ::-1]), c))
    nodes, quads = Torus(1.0, 0.4).mesh_quads(12)
    yield "torus quads", nodes, [quads]
    yield "torus quads inside out", nodes, [quads[:, ::-1]]
    tri = np.concatenate([quads[:40, [0, 1, 2]], quads[:40, [0, 2, 3]]])
    yield "mixed", nodes, [quads[40:], tri]
    n = len(x)
    dup = np.arange(0, n, 4)
    xs = np.concatenate([x, x[dup]])
    seam = f.copy()
    at = np.isin(seam[:, 1], dup)
    seam[at, 1] = n + np.searchsorted(dup, seam[at, 1])
    yield "seam", xs, [seam]


@pytest.mark.parametrize("case", [c[0] for c in _cases()])
def test_inside_out_is_the_former(case):
    name, nodes, faces = next(c for c in _cases() if c[0] == case)
    for ident in (None, _segment.node_identity(nodes)):
        new = inside_out(nodes, faces, ident)
        old = ref.inside_out(nodes, faces, ident)
        assert type(new[0]) is type(old[0]) and new[0] == old[0]
        assert np.float64(new[1]).tobytes() == np.float64(old[1]).tobytes()
    # the pass's arrays against numpy's former expressions
    key = _segment.node_identity(nodes)
    blocks = [np.asarray(f)[:, :4 if f.shape[1] in (4, 8, 9) else 3] for f in faces]
    edges = _segment.edge_table(blocks, key)
    F = sum(len(b) for b in blocks)
    two = np.diff(edges.start) == 2
    at = edges.start[:-1][two]
    h0, h1 = edges.order[at], edges.order[at + 1]
    way = edges.forward[h0] != edges.forward[h1]
    good = np.zeros(edges.ne, bool)
    good[two] = way
    a, b, open_facet = _edges.closed_pairs(edges.start, edges.order, edges.fac,
                                           np.ascontiguousarray(edges.forward, np.int8), F)
    assert np.array_equal(a, edges.fac[h0[way]]) and np.array_equal(b, edges.fac[h1[way]])
    expect = np.zeros(F, bool)
    expect[edges.fac[~good[edges.edge]]] = True
    assert np.array_equal(open_facet.view(bool), expect)


@pytest.mark.parametrize("kind", [dict(order=2), dict(order=2, quads=True),
                                  dict(order=2, quads=True, incomplete=True)])
def test_second_order(tmp_path, kind):
    """Second-order cells: their corners close the surface."""
    pytest.importorskip("gmsh")
    from diffsurf_cli import io
    from diffsurf_cli.testing import gmsh_scenes

    target = io.read_target(gmsh_scenes.sphere_surface(tmp_path / "s.msh", size=0.4, **kind))
    faces = [np.asarray(c) for _, c in target.cells]
    for fs in (faces, [f[:, ::-1] for f in faces]):
        new, old = inside_out(target.points, fs), ref.inside_out(target.points, fs)
        assert new[0] == old[0] and np.float64(new[1]).tobytes() == np.float64(old[1]).tobytes()
