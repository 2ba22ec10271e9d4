"""The oracle of the frame's per-facet and per-node passes (issue 36): `facet_area_vectors`
and `node_normals` as they were (numpy's cross products, one `np.add.at` pass per block and
column), and the grid of the diffuse engine's nodes (`mls._search.build_grid`: a stable
argsort of the cells' linear indices, and searchsorted for each cell's start). Pure numpy,
kept out of the package; tests/test_frame_fast.py compares the package with it, bit for bit."""
from __future__ import annotations

import numpy as np

from diffsurf_cli.mls.frame import facet_corners

#: mls._search.MAX_CELLS_PER_NODE as build_grid read it
MAX_CELLS_PER_NODE = 8


def facet_area_vectors(points: np.ndarray, faces: list[np.ndarray]) -> np.ndarray:
    """frame.facet_area_vectors as it was: half the cross product of two edges (triangles) or
    of the diagonals (quads), numpy's np.cross."""
    parts = []
    for f in faces:
        f = facet_corners(f)
        if f.shape[1] == 3:
            a, b, c = (points[f[:, i]] for i in range(3))
            parts.append(0.5 * np.cross(b - a, c - a))
        else:
            a, b, c, d = (points[f[:, i]] for i in range(4))
            parts.append(0.5 * np.cross(c - a, d - b))
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def node_normals(points: np.ndarray, faces: list[np.ndarray]) -> np.ndarray:
    """frame.node_normals as it was: np.add.at of each facet's vector onto every node of the
    facet, block by block and column by column."""
    normals = np.zeros_like(points, dtype=np.float64)
    if len(points):
        centre = points.mean(axis=0)
        size = np.abs(points - centre).max()
        points = np.ldexp(points - centre, -int(np.frexp(size)[1])) if size > 0 else points
    areas = facet_area_vectors(points, faces)
    start = 0
    for f in faces:
        block = areas[start:start + len(f)]
        start += len(f)
        for j in range(f.shape[1]):
            np.add.at(normals, f[:, j], block)
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, norm, out=np.zeros_like(normals), where=norm > 0)


def facet_volumes(nodes: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """projection.inside_out's per-facet volume as it was (times 6): x0 . (x1 x x2), plus
    x0 . (x2 x x3) for quads, about the centre of the nodes' box; corners (F, 4), -1 past a
    triangle's third."""
    x = np.asarray(nodes, dtype=np.float64)
    x = x - 0.5 * (x.min(axis=0) + x.max(axis=0))
    c = x[np.maximum(corners, 0)]
    vol = np.einsum("fi,fi->f", c[:, 0], np.cross(c[:, 1], c[:, 2]))
    quad = corners[:, 3] >= 0
    vol[quad] += np.einsum("fi,fi->f", c[quad, 0], np.cross(c[quad, 2], c[quad, 3]))
    return vol


def build_grid(coords, cell: float):
    """mls._search.build_grid as it was: (lo, cell, dims, start, order)."""
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    n = len(coords)
    lo = coords.min(axis=0) if n else np.zeros(3)
    span = coords.max(axis=0) - lo if n else np.zeros(3)
    if not cell > 0:
        cell = 1.0
    limit = max(MAX_CELLS_PER_NODE * n, 64)
    while True:
        dims = np.maximum(np.floor(span / cell).astype(np.int64) + 1, 1)
        if np.prod(dims.astype(np.float64)) <= limit:
            break
        cell *= 1.25
    ijk = np.minimum(((coords - lo) / cell).astype(np.int64), dims - 1)
    lin = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(lin, kind="stable").astype(np.int64)
    start = np.searchsorted(lin[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
    return lo, float(cell), dims, start, order


def is_height_field(axes: np.ndarray, area_vectors: np.ndarray) -> bool:
    """frame.is_height_field as it was (numpy's reductions along each row)."""
    from diffsurf_cli.mls.frame import AUTO_MAX_SLOPE_DEG

    top = np.abs(area_vectors).max(axis=1, initial=0.0)
    v = area_vectors[top > 0] / top[top > 0, None]
    if len(v) == 0:
        return False
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    return bool(np.min(n @ axes[2]) > np.cos(np.radians(AUTO_MAX_SLOPE_DEG)))
