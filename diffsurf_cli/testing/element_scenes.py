"""Targets with contactors pushed into them, for the contact element's checks: its Taylor
tests (tests/test_element.py), its agreement with the jet oracle (tests/test_element_engine.py,
benchmarks/element_oracle.py).

Each scene is a function returning ``(nodes, faces, points, options)``: the target's nodes and
facet blocks, contactors inside it (penetrating) and the `DiffuseSurface` options it is built
with.
"""
from __future__ import annotations

import numpy as np

from ..mls.surface import DiffuseSurface
from ..projection import PENETRATION
from .shapes import Cylinder, Saddle, Sphere, Torus


def _inside_sphere():
    """Icosphere, contactors pushed inside (penetration), local frames."""
    shape = Sphere(center=(0.2, -0.1, 0.3), radius=1.0)
    nodes, faces = shape.mesh(5)
    on = shape.sample_near(3, 0.0, rng=11)
    _, normal, _ = shape.closest(on)
    points = on - 0.06 * normal
    return nodes, [faces], points, {"frame": "auto"}


def _saddle_global():
    """Saddle height field, triangles, the global mean-plane frame."""
    shape = Saddle(a=0.5, size=1.0)
    nodes, faces = shape.mesh(10)
    on = shape.sample_near(3, 0.0, rng=12, margin=0.35)
    _, normal, _ = shape.closest(on)
    points = on - 0.04 * normal
    return nodes, [faces], points, {"frame": "global"}


def _cylinder_quads():
    """Full cylinder of radius 10 (mm-sized coordinates), quads, contactors inside."""
    shape = Cylinder(radius=10.0, length=20.0, center=(32.5, 30.0, 2.5))
    nodes, quads = shape.mesh_quads(24)
    on = shape.sample_near(3, 0.0, rng=13, margin=6.0)
    _, normal, _ = shape.closest(on)
    points = on - 0.5 * normal
    return nodes, [quads], points, {"frame": "auto"}


#: The Taylor-tested scenes.
SCENES = {"sphere": _inside_sphere, "saddle": _saddle_global, "cylinder": _cylinder_quads}


def _torus():
    """Closed torus of quads, contactors inside the tube, local frames."""
    shape = Torus(major=1.0, minor=0.4)
    nodes, quads = shape.mesh_quads(40)
    on = shape.sample_near(3, 0.0, rng=14)
    _, normal, _ = shape.closest(on)
    return nodes, [quads], on - 0.03 * normal, {"frame": "local"}


def _saddle_local():
    """Saddle of quads in local (PCA) frames instead of the global mean plane."""
    shape = Saddle(a=0.5, size=1.0)
    nodes, quads = shape.mesh_quads(12)
    on = shape.sample_near(3, 0.0, rng=15, margin=0.35)
    _, normal, _ = shape.closest(on)
    return nodes, [quads], on - 0.05 * normal, {"frame": "local"}


#: Those and a torus and a saddle in local frames.
ALL_SCENES = dict(SCENES, torus=_torus, saddle_local=_saddle_local)


def pairing(scene, basis, weight):
    """A scene's surface (`basis`, `weight`, radius 2), its contactors, their projection with
    the pairing kept, and the rows of the penetrating ones (at least two)."""
    nodes, faces, points, extra = ALL_SCENES[scene]()
    surf = DiffuseSurface(nodes, faces, basis=basis, weight=weight, support="radius",
                          radius=2.0, **extra)
    proj = surf.project(points, keep_patch=True)
    rows = np.flatnonzero(proj.status == PENETRATION)
    assert len(rows) >= 2, f"{scene}: statuses {proj.status}"
    return surf, points, proj, rows
