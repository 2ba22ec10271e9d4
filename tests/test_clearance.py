"""The facets' clearances (`patches.clearance`): a lower bound of the distance from every point
of a facet to every point of a sharp or smooth edge, and to the facets of the patches beyond
its vertex ring less their guard bound, so that the compiled pass may skip a search where it
proves it would find nothing (its answers are those of the search: here, and
tests/test_patches.py, tests/test_threads.py)."""
from __future__ import annotations

import numpy as np

from diffsurf_cli.patches import _pass
from diffsurf_cli.patches.clearance import feature_clearance, foreign_clearance
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.testing.shapes import Sphere

SHARP, SMOOTH = (_pass.EDGE_CLASSES.index(c) for c in ("sharp", "smooth"))


def _box(n=6):
    """The surface of the unit cube, n x n quads a face split in triangles (12 sharp edges)."""
    t = np.linspace(0.0, 1.0, n + 1)
    nodes, faces = [], []
    for axis in range(3):
        for side in (0.0, 1.0):
            u, v = np.meshgrid(t, t, indexing="ij")
            p = np.zeros((n + 1, n + 1, 3))
            p[..., axis] = side
            p[..., (axis + 1) % 3] = u
            p[..., (axis + 2) % 3] = v
            base = sum(len(x) for x in nodes)
            nodes.append(p.reshape(-1, 3))
            idx = base + np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
            a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
            tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                                  np.stack([a, c, d], -1).reshape(-1, 3)])
            if side == 0.0:
                tri = tri[:, ::-1]
            faces.append(tri)
    return np.concatenate(nodes), np.concatenate(faces)


def _samples(a, b, k):
    """k points on each segment a -> b (endpoints included)."""
    s = np.linspace(0.0, 1.0, k)[None, :, None]
    return (a[:, None] + s * (b - a)[:, None]).reshape(-1, 3)


def test_a_lower_bound_of_the_distance_to_the_features():
    nodes, faces = _box()
    surf = PatchedSurface(nodes, [faces])
    assert surf.npatches == 6
    corner = nodes[np.maximum(surf.corners, 0)]
    clear = feature_clearance(corner, surf.kind, surf.edge_class, (SHARP, SMOOTH), 1e-12)
    # the cube's 12 edges, densely sampled, and points all over each facet
    feature = surf.edge_class[:, :3] == SHARP
    a = corner[:, :3][feature]
    b = corner[:, [1, 2, 0]][feature]
    edge_points = _samples(a, b, 9)
    w = np.random.default_rng(1).dirichlet(np.ones(3), size=40)
    on_facet = np.einsum("kj,fjd->fkd", w, corner[:, :3])               # (F, 40, 3)
    d = np.linalg.norm(on_facet[:, :, None] - edge_points[None, None], axis=-1).min(axis=(1, 2))
    assert np.all(clear <= d + 1e-12)
    assert np.all(clear[d < 1e-9] == 0)           # facets on an edge: no clearance
    assert (clear > 0).mean() > 0.3                # the faces' middles have some


def test_no_feature_no_bound():
    nodes, faces = Sphere().mesh(5)
    surf = PatchedSurface(nodes, [faces], feature_angle=None)
    corner = nodes[np.maximum(surf.corners, 0)]
    clear = feature_clearance(corner, surf.kind, surf.edge_class, (SHARP, SMOOTH), 1e-12)
    assert np.all(np.isinf(clear))


def _patched_answers(surf, points):
    res = surf.project(points)
    return {f: np.asarray(getattr(res, f)) for f in
            ("gap", "normal", "proximal_point", "status", "reason", "source", "support",
             "iterations", "rcond", "curvature", "terms", "facet", "facet_gap")}


def test_a_lower_bound_of_the_distance_to_foreign_patches():
    """foreign_clearance[f] <= dist(y, z) - bound[g] for y on f, z on any facet g of a patch
    that is not one of f's candidates (sampled: the samples' distances are at least the
    true ones), with bounds that differ from facet to facet."""
    nodes, faces = _box(3)
    surf = PatchedSurface(nodes, [faces])
    corner = nodes[np.maximum(surf.corners, 0)]
    F = len(corner)
    bound = np.random.default_rng(2).uniform(0.0, 2.0, F)  # up to the cube's size
    clear = foreign_clearance(corner, surf.kind, surf.label, surf.ring_ptr, surf.ring_patches,
                              bound)
    w = np.random.default_rng(1).dirichlet(np.ones(3), size=30)
    on_facet = np.einsum("kj,fjd->fkd", w, corner[:, :3])               # (F, 30, 3)
    sampled = np.empty(F)
    for f in range(F):
        mine = surf.ring_patches[surf.ring_ptr[f]:surf.ring_ptr[f + 1]]
        g = np.flatnonzero(~np.isin(surf.label, mine))
        d = np.linalg.norm(on_facet[f][:, None, None] - on_facet[g][None], axis=-1)
        sampled[f] = (d.min(axis=(0, 2)) - bound[g]).min()
    assert np.all(clear <= sampled + 1e-12)
    # and useful: within two facets' reach (a facet 1/3 wide: 0.24) of the truth
    assert np.all(sampled - clear < 4 * 0.24), (sampled - clear).max()


def _skip_changes_nothing(nodes, faces, monkeypatch, **kw):
    """The pass's answers with its skips (the feature search where the clearance proves it
    would find no feature, the foreign search where no foreign patch can be near) are those
    of the searches done for every contactor."""
    rng = np.random.default_rng(3)
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    w = 0.05 * np.linalg.norm(hi - lo)
    points = rng.uniform(lo - w, hi + w, (4000, 3))
    fast = _patched_answers(PatchedSurface(nodes, faces, **kw), points)
    monkeypatch.setattr(_pass, "feature_clearance", lambda corner, *a: np.zeros(len(corner)))
    monkeypatch.setattr(_pass, "foreign_clearance",
                        lambda corner, *a: np.full(len(corner), -np.inf))
    slow = _patched_answers(PatchedSurface(nodes, faces, **kw), points)
    for key in fast:
        assert fast[key].tobytes() == slow[key].tobytes(), key


def test_skipping_the_search_changes_no_answer_on_a_cube(monkeypatch):
    nodes, faces = _box(8)
    _skip_changes_nothing(nodes, [faces], monkeypatch)


def test_skipping_the_search_changes_no_answer_on_a_filleted_box(tmp_path, monkeypatch):
    import pytest

    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import read_surface
    from diffsurf_cli.testing import gmsh_scenes

    target, nodes, faces = read_surface(gmsh_scenes.fillet_box(tmp_path / "fb.msh", size=0.1))
    _skip_changes_nothing(nodes, faces, monkeypatch, tags=np.concatenate(target.tags),
                          smooth_tags=target.faces_tagged)


def test_skipping_the_search_changes_no_answer_on_a_thin_shell(monkeypatch):
    """A spherical shell 0.04 thick under facets of sag 0.017, its two faces two patches:
    the far face is near the contactors inside it and in its cavity (the foreign search
    changes 165 of the 4000 answers; it is skipped for most of the others)."""
    outer, tri = Sphere().mesh(3)
    nodes = np.vstack([outer, 0.96 * outer])
    faces = np.vstack([tri, tri[:, ::-1] + len(outer)])
    _skip_changes_nothing(nodes, [faces], monkeypatch)
