"""The grid's k-d tree (`mls._search.build_tree`, issue 36: the coordinates swapped along with
perm, read in order) is bit for bit the former code's (tests/reference_tree.py): its boxes,
spans and permutation, and the tree's coordinates (`GridArrays`' tree_coords: coords[perm]),
on random clouds, ties and duplicates, signed zeros, planar and collinear nodes, a sphere's
nodes."""
from __future__ import annotations

import numpy as np
import pytest

import reference_tree as ref
from diffsurf_cli.mls import _search


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _clouds():
    rng = np.random.default_rng(7)
    yield rng.normal(size=(1, 3))
    yield rng.normal(size=(9, 3))
    yield rng.normal(size=(300, 3))
    yield rng.integers(0, 4, size=(257, 3)).astype(float)          # ties, duplicates
    z = rng.integers(-1, 2, size=(200, 3)) * 0.0                   # +0 and -0 only
    z[rng.random((200, 3)) < 0.5] *= -1.0
    yield z
    p = rng.normal(size=(150, 3))
    p[:, 2] = 0.0
    yield p                                                        # planar
    yield np.outer(rng.normal(size=120), [1.0, 2.0, -0.5])         # collinear
    yield np.repeat(rng.normal(size=(5, 3)), 40, axis=0)           # coincident groups
    trimesh = pytest.importorskip("trimesh")
    yield np.asarray(trimesh.creation.icosphere(subdivisions=3).vertices)


@pytest.mark.parametrize("leaf", [1, 3, 8])
def test_tree_is_the_former(leaf):
    for coords in _clouds():
        old = ref.build_tree(coords, leaf)
        new = _search.build_tree(coords, leaf)
        for a, b in zip(new, old):
            assert _same(a, b)
        box, span, perm, xs = _search._build_tree(coords, leaf)
        assert _same(xs, np.ascontiguousarray(np.asarray(coords, dtype=np.float64)[perm]))

