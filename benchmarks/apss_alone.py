"""MeshLab APSS alone in a fresh process: the projection call on the 200k points of
compare.py's speed targets, three times, and nothing else.

    python benchmarks/apss_alone.py

Inside compare.py's run the same call sometimes took 3x longer (0.58-0.60 s against 0.19 s
here); the cause is not found (see its speed_targets).
"""

import numpy as np

from compare import apss_project
from diffsurf_cli.testing.shapes import Sphere

nodes, faces = Sphere(radius=1.0).mesh(13)
rng = np.random.default_rng(5)
n = 200000
u = rng.standard_normal((n, 3))
u /= np.linalg.norm(u, axis=1, keepdims=True)
points = u * rng.uniform(0.95, 1.05, n)[:, None]
for _ in range(3):
    _, _, call, total = apss_project(nodes, faces, points)
    print(f"APSS call {call:.3f} s, with set-up {total:.3f} s")
