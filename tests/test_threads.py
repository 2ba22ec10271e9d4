"""Threads that pay (issue 20): every compiled loop over contactors takes its thread count from
`threads.threads_for` (one thread, a plain loop, below its kernel's crossover), and its answers
are the same, bit for bit, on one thread and on several. No timings here
(benchmarks/crossover.py and benchmarks/patch_speed.py measure them)."""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli import threads, tol
from diffsurf_cli.element.element import contact
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls import _search
from diffsurf_cli.mls.frame import facet_corners
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.testing.shapes import Sphere

#: every compiled entry point with a parallel loop, by its key in tol.PARALLEL_MIN
KERNELS = {"project", "project_with", "pass", "facets", "elements", "supports", "rigid",
           "nearest", "facet_elements", "quadric"}


def test_every_kernel_has_a_crossover():
    assert set(tol.PARALLEL_MIN) == KERNELS
    assert all(isinstance(v, int) and v >= 1 for v in tol.PARALLEL_MIN.values())


def test_one_thread_below_the_crossover_one_per_half_crossover_above(monkeypatch):
    monkeypatch.setattr(threads, "max_threads", lambda: 8)
    c = tol.PARALLEL_MIN["pass"]
    assert threads.threads_for(0, "pass") == 1
    assert threads.threads_for(c - 1, "pass") == 1
    assert threads.threads_for(c, "pass") == 2
    assert threads.threads_for(2 * c, "pass") == 4
    assert threads.threads_for(100 * c, "pass") == 8
    monkeypatch.setattr(threads, "max_threads", lambda: 1)
    assert threads.threads_for(100 * c, "pass") == 1


def test_chunks_give_each_thread_several():
    assert threads.chunk_size(10_000, 2, 64) == 64
    assert threads.chunk_size(64, 2, 64) == 8
    assert threads.chunk_size(3, 2, 64) == 1


@pytest.fixture(scope="module")
def scene():
    nodes, faces = Sphere().mesh(6)
    rng = np.random.default_rng(5)
    points = Sphere().sample_near(600, 0.05, rng)
    points[7] = np.nan  # a bad point takes the same path on every thread count
    return nodes, faces, points


def _answers(nodes, faces, points):
    """Every compiled loop's answers on this scene, as a flat dict of arrays."""
    plain = DiffuseSurface(nodes, [faces])
    patched = PatchedSurface(nodes, [faces], feature_angle=None)
    facets = FacetSurface(nodes, [facet_corners(faces)])
    out = {}

    def put(name, obj, fields):
        for f in fields:
            value = getattr(obj, f)
            if value is not None:
                out[f"{name}.{f}"] = np.asarray(value)

    proj = ("gap", "normal", "proximal_point", "status", "reason", "support", "iterations",
            "rcond", "curvature", "terms")
    first = plain.project(points, keep_patch=True)
    put("plain", first, proj)
    put("plain.patch", first.patch, ("origin", "axes", "radius", "spacing", "index",
                                     "reduced", "direction"))
    put("with", plain.project_with(points, first.patch), proj)
    put("patched", patched.project(points), proj + ("source", "facet", "facet_gap"))
    put("facets", facets.project(points), proj + ("facet", "param"))
    for name, surf in (("c-plain", plain), ("c-patched", patched), ("c-facets", facets)):
        for rigid in (False, True):
            c = contact(surf, points, rigid_target=rigid)
            put(f"{name}.{rigid}", c, ("contactor", "nodes", "gap", "N", "M"))
    out["nearest"] = _search.nearest_distances(nodes, 6, points[np.isfinite(points[:, 0])])
    return out


def test_the_same_answers_on_one_thread_and_on_several(scene, monkeypatch):
    """Forced serial (a huge crossover) against forced parallel (crossover 1, two threads
    even where OpenMP would give one): identical arrays."""
    monkeypatch.setattr(tol, "PARALLEL_MIN", {k: 1 << 62 for k in KERNELS})
    serial = _answers(*scene)
    monkeypatch.setattr(tol, "PARALLEL_MIN", {k: 1 for k in KERNELS})
    monkeypatch.setattr(threads, "max_threads", lambda: 2)
    parallel = _answers(*scene)
    assert serial.keys() == parallel.keys()
    for key in serial:
        a, b = serial[key], parallel[key]
        assert a.shape == b.shape and a.tobytes() == b.tobytes(), key


@pytest.mark.parametrize("env, expected", [({}, "0"), ({"GOMP_SPINCOUNT": "5000"}, "5000"),
                                           ({"OMP_WAIT_POLICY": "active"}, None)])
def test_idle_threads_sleep_unless_the_user_chose(env, expected):
    """GOMP_SPINCOUNT is set before libgomp loads (diffsurf_cli/__init__.py), only where the
    user set neither it nor OMP_WAIT_POLICY."""
    import os
    import subprocess
    import sys

    base = {k: v for k, v in os.environ.items()
            if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    code = ("import os, diffsurf_cli.threads as t; t.max_threads(); "
            "print(os.environ.get('GOMP_SPINCOUNT'))")
    out = subprocess.run([sys.executable, "-c", code], env={**base, **env}, check=True,
                         capture_output=True, text=True).stdout.strip()
    assert out == str(expected)
