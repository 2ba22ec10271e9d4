"""Resample a faceted surface onto its diffuse surface (`diffsurf smooth`).

The facets are refined uniformly (each triangle into 4 triangles, each quad into 4 quads, edge
midpoints shared), then every vertex is moved to its proximal point on the diffuse surface of
the **original** nodes: the same engine as `project`. With approximant weights the original
nodes move too (the paper's "décollement", §5); `keep_nodes` pins them.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .mls.surface import DiffuseSurface
from .projection import OUTSIDE


@dataclass
class Smoothed:
    """A smoothed surface.

    vertices : (v, 3) float
    faces : list of (f, 3) or (f, 4) int      triangles and quads
    point_data : dict of str to array         normal (v, 3), k1, k2 (principal curvatures,
                                              > 0 convex), moved (distance each vertex moved),
                                              placed (1: on the diffuse surface, or on the
                                              target's curved cells where they answer; 0:
                                              left on
                                              the facets: no usable support there, a sharp
                                              edge, or the guard: the diffuse surface there
                                              differs from the facets by more than smoothing
                                              them can explain)
    node_deviation : float                    largest distance an original node moved (0 with
                                              keep_nodes, or with interpolating weights)
    unplaced : int                            vertices left on the facets
    """

    vertices: np.ndarray
    faces: list
    point_data: dict
    node_deviation: float
    unplaced: int


def refine(vertices: np.ndarray, faces: list[np.ndarray], levels: int = 1):
    """Uniform subdivision, `levels` times; the original vertices keep their indices first.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : list of (f, 3) or (f, 4) int
    levels : int

    Returns
    -------
    vertices : (v, 3) float
    faces : list of (f', 3) or (f', 4) int, 4**levels times as many faces
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    for _ in range(levels):
        edges = np.concatenate([np.stack([f, np.roll(f, -1, axis=1)], -1).reshape(-1, 2)
                                for f in faces]) if faces else np.zeros((0, 2), np.int64)
        key = np.sort(edges, axis=1)
        unique, inverse = np.unique(key, axis=0, return_inverse=True)
        n = len(vertices)
        vertices = np.vstack([vertices, vertices[unique].mean(axis=1)])
        mids = n + inverse.reshape(-1)
        out, start = [], 0
        for f in faces:
            k = f.shape[1]
            mid = mids[start:start + len(f) * k].reshape(len(f), k)  # mid[:, j]: edge j -> j+1
            start += len(f) * k
            if k == 3:
                out.append(np.concatenate([
                    np.stack([f[:, 0], mid[:, 0], mid[:, 2]], 1),
                    np.stack([mid[:, 0], f[:, 1], mid[:, 1]], 1),
                    np.stack([mid[:, 2], mid[:, 1], f[:, 2]], 1),
                    np.stack([mid[:, 0], mid[:, 1], mid[:, 2]], 1)]))
            else:
                centre = np.arange(len(vertices), len(vertices) + len(f))
                vertices = np.vstack([vertices, vertices[f].mean(axis=1)])
                out.append(np.concatenate([
                    np.stack([f[:, 0], mid[:, 0], centre, mid[:, 3]], 1),
                    np.stack([mid[:, 0], f[:, 1], mid[:, 1], centre], 1),
                    np.stack([centre, mid[:, 1], f[:, 2], mid[:, 2]], 1),
                    np.stack([mid[:, 3], centre, mid[:, 2], f[:, 3]], 1)]))
        faces = out
    return vertices, faces


#: Memory of a smoothing per output vertex and per output facet, in bytes: measured peaks
#: (tracemalloc) were 240-440 per vertex in all for triangles and quads at 3-4 levels; these
#: round up, so the estimate errs on the large side.
BYTES_PER_VERTEX = 320
BYTES_PER_FACET = 96


def refined_size(faces: list[np.ndarray], levels: int, n_vertices: int | None = None):
    """Vertices and facets after `levels` uniform subdivisions, counted without building them.

    Each level adds a vertex per edge (and one per quad: its centre), and splits each facet
    in 4, each edge in 2 and adds 3 edges inside a triangle, 4 inside a quad.

    Returns (vertices, facets) as Python ints (exact, however large).
    """
    faces = [np.asarray(f, dtype=np.int64) for f in faces if len(f)]
    if not faces:
        return int(n_vertices or 0), 0
    edges = np.unique(np.sort(np.concatenate(
        [np.stack([f, np.roll(f, -1, axis=1)], -1).reshape(-1, 2) for f in faces]), axis=1),
        axis=0)
    v = int(n_vertices) if n_vertices is not None else len(np.unique(np.concatenate(
        [f.ravel() for f in faces])))
    e = len(edges)
    tri = sum(len(f) for f in faces if f.shape[1] == 3)
    quad = sum(len(f) for f in faces if f.shape[1] == 4)
    for _ in range(levels):
        v, e = v + e + quad, 2 * e + 3 * tri + 4 * quad
        tri, quad = 4 * tri, 4 * quad
    return v, tri + quad


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux: MemAvailable), or None when the
    system does not say."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_size(faces: list[np.ndarray], levels: int, available: int | None = None) -> int:
    """The estimated bytes of smoothing `faces` `levels` times; raises MemoryError, before
    anything is built, when that exceeds the `available` memory (default: what the system
    reports)."""
    vertices, facets = refined_size(faces, levels)
    need = vertices * BYTES_PER_VERTEX + facets * BYTES_PER_FACET
    available = available_memory() if available is None else available
    if available is not None and need > available:
        raise MemoryError(f"{levels} subdivision levels would make {vertices:.3g} vertices and "
                          f"{facets:.3g} facets, about {_size(need)} of memory; "
                          f"{_size(available)} is available: use fewer levels or a longer "
                          f"edge length")
    return need


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"


def levels_for(vertices: np.ndarray, faces: list[np.ndarray], edge_length: float) -> int:
    """Subdivision levels that bring the longest facet edge to at most `edge_length`."""
    if not edge_length > 0:
        raise ValueError(f"edge length must be > 0, got {edge_length}")
    longest = max((np.linalg.norm(vertices[f] - vertices[np.roll(f, -1, axis=1)], axis=-1).max()
                   for f in faces if len(f)), default=0.0)
    return int(max(0, np.ceil(np.log2(longest / edge_length)))) if longest > 0 else 0


def smooth(surface: DiffuseSurface, faces: list[np.ndarray], levels: int = 1,
           keep_nodes: bool = False, progress=None) -> Smoothed:
    """Refine the facets of `surface` and place every vertex on its diffuse surface.

    Parameters
    ----------
    surface : DiffuseSurface or PatchedSurface
        Built on the original nodes; its options (basis, weight, support, frame) apply. A
        PatchedSurface's facets and guard apply too: a vertex its facets answer stays where
        it is.
    faces : list of (f, 3) or (f, 4) int
        Facets (corners) indexing ``surface.nodes``.
    levels : int
        Uniform subdivisions.
    keep_nodes : bool
        Pin the original facet corners where they are.
    progress : callable, optional
        Called as ``progress(done)`` with the number of refined vertices placed so far (the
        projection's chunks; `refined_size` gives the total beforehand).

    Returns
    -------
    Smoothed

    Raises
    ------
    MemoryError
        Before anything is built, when the refined surface would not fit in the available
        memory (`check_size`).
    """
    check_size(faces, levels)
    used = np.unique(np.concatenate([f.ravel() for f in faces]))
    # keep only facet corners (mid-side nodes of higher-order cells feed the fit, not the mesh)
    remap = np.full(len(surface.nodes), -1)
    remap[used] = np.arange(len(used))
    vertices, out_faces = refine(surface.nodes[used], [remap[f] for f in faces], levels)
    proj = surface.project(vertices, progress=progress)
    placed = proj.status < OUTSIDE
    if proj.source is not None:  # a PatchedSurface: where its facets answered, the vertex
        from .patches.surface import CELLS  # stays, but its curved cells place it

        placed &= (proj.source >= 0) | (proj.source == CELLS)
    new = np.where(placed[:, None], proj.proximal_point, vertices)
    original = np.arange(len(used))
    deviation = np.linalg.norm(new[original] - vertices[original], axis=1)
    node_deviation = float(np.max(deviation, initial=0.0))
    if keep_nodes:
        new[original] = vertices[original]
    moved = np.linalg.norm(new - vertices, axis=1)
    point_data = {
        "normal": np.nan_to_num(proj.normal), "k1": proj.curvature[:, 0],
        "k2": proj.curvature[:, 1], "moved": moved, "placed": placed.astype(np.int64)}
    return Smoothed(new, out_faces, point_data, node_deviation, int((~placed).sum()))
