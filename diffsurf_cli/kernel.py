"""Compiled projection kernel: `DiffuseSurface.select` and `DiffuseSurface._solve`, one contactor
at a time, in parallel over blocks of contactors (plain C with OpenMP, _ckernel.c, built by
``pip install`` and called through ctypes; this module is its Python face).

The numpy path in surface.py is the slow, obvious reference; this kernel computes the same
quantities with the same rules, and tests/test_kernel.py checks one against the other. What
differs is only how, never what:

- neighbours come from a uniform grid of cells instead of a k-d tree (same sets: all nodes within
  a radius, or the k nearest);
- a radius support is collected in grid order, not sorted by distance (it is a set; only its
  three nearest nodes, which orient the sheet test, are moved first), so sums run in another
  order and agree with the reference to round-off;
- the weighted least squares [15]-[17] is solved by Householder QR of W^½ P (columns
  equilibrated as in fit.py) instead of an SVD; the condition number σ_min/σ_max of the small
  triangular factor R (those of W^½ P) comes from the extreme eigenvalues of RᵀR (tridiagonal
  QL) when it is at least 1e-2, else from one-sided Jacobi on R (RᵀR squares the conditioning);
- the local frame's smallest-spread direction comes from a 3x3 Jacobi eigen-solver.

Everything is per point and allocation-free inside the loop (scratch once per block of rows),
so memory is the outputs only. The C code was first ported from a numba kernel operation for
operation (bit for bit the same results), then made faster as above.
"""
from __future__ import annotations

import ctypes

import numpy as np

from . import _native
from .mls import basis as _basis
from . import tol
from .mls import weight as weight_mod
from ._native import F64, I64
from .mls.frame import _E1_GUIDE, _E1_GUIDE_ALT

WEIGHT_CODES = {"wendland": 0, "gauss": 1, "singular": 2}
#: Grid cells per node at most (a dense grid over the bounding box of a sparse, elongated
#: target could otherwise be huge); the cell grows until the grid fits.
_MAX_CELLS_PER_NODE = 8
#: Grid cell size in node spacings (support balls are 2-5 spacings wide).
_CELL_SPACINGS = 2.0


# --------------------------------------------------------------------------------------------
# the grid of cells
# --------------------------------------------------------------------------------------------


def build_grid(coords: np.ndarray, cell: float):
    """A uniform grid over `coords` (n, 3): (lo, cell, dims, start, order).

    Nodes of cell c are ``order[start[c]:start[c + 1]]``; cell indices are
    (i * dims[1] + j) * dims[2] + k.
    """
    coords = np.ascontiguousarray(coords, dtype=np.float64)
    n = len(coords)
    lo = coords.min(axis=0)
    span = coords.max(axis=0) - lo
    cell = float(cell) if cell > 0 else 1.0
    limit = max(_MAX_CELLS_PER_NODE * n, 64)
    while True:
        dims = np.maximum(np.floor(span / cell).astype(np.int64) + 1, 1)
        if np.prod(dims.astype(np.float64)) <= limit:
            break
        cell *= 1.25
    ijk = np.minimum(((coords - lo) / cell).astype(np.int64), dims - 1)
    lin = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(lin, kind="stable").astype(np.int64)
    start = np.searchsorted(lin[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
    return lo, cell, dims, start, order


def constants():
    """The tolerances and weight constants the kernel uses, as one array (indexed by the K_*
    names of _ckernel.c)."""
    return np.array([weight_mod._GAUSS_C2, float(weight_mod._GAUSS_TAIL), tol.SINGULAR_FLOOR,
                     tol.NEWTON_STEP, float(tol.NEWTON_MAX_ITER), *_E1_GUIDE, *_E1_GUIDE_ALT,
                     tol.EQUILIBRATION_FLOOR])


def exponents(basis: str):
    """Exponent arrays (a, b) of the monomials s^a t^b of a basis, for the kernel."""
    e = np.array(_basis.EXPONENTS[basis], dtype=np.int64)
    return np.ascontiguousarray(e[:, 0]), np.ascontiguousarray(e[:, 1])


# --------------------------------------------------------------------------------------------
# the C side: structures of _ckernel.c and argument types
# --------------------------------------------------------------------------------------------

_P64 = ctypes.POINTER(ctypes.c_double)
_PI64 = ctypes.POINTER(ctypes.c_int64)
_PI8 = ctypes.POINTER(ctypes.c_int8)
_PU8 = ctypes.POINTER(ctypes.c_uint8)
_I = ctypes.c_int64
_D = ctypes.c_double


class _Grid(ctypes.Structure):
    _fields_ = [("coords", _P64), ("lo", _P64), ("cell", _D), ("dims", _PI64),
                ("start", _PI64), ("order", _PI64)]


class _Target(ctypes.Structure):
    _fields_ = [("nodes", _P64), ("normals", _P64), ("node_spacing", _P64), ("first", _PI64),
                ("fold_normals", _P64), ("is_signed", _PU8), ("steep", _PU8),
                ("grid", _Grid), ("plane", _Grid), ("frame_origin", _P64), ("frame_axes", _P64),
                ("has_faces", _I), ("duplicates", _I), ("global_frame", _I)]


class _Options(ctypes.Structure):
    _fields_ = [("ea", _PI64), ("eb", _PI64), ("nterms", _I),
                ("weight_code", _I), ("knn", _I), ("k", _I), ("spacing_neighbours", _I),
                ("radius", _D), ("frame_ball", _D), ("knn_factor", _D), ("sheet_cos", _D),
                ("cos_fold", _D), ("rcond_min", _D), ("contact_tol", _D),
                ("outside_spacings", _D), ("hull_spacings", _D), ("consts", _P64)]


class _Outputs(ctypes.Structure):
    _fields_ = [("gap", _P64), ("normal", _P64), ("proximal", _P64), ("status", _PI8),
                ("reason", _PI8), ("support", _PI64), ("iterations", _PI64), ("rcond", _P64),
                ("curvature", _P64), ("origin", _P64), ("axes", _P64), ("radius", _P64),
                ("spacing", _P64), ("index", _PI64), ("width", _I), ("overflow", _PU8)]


_LIB = None


def _lib():
    global _LIB
    if _LIB is None:
        lib = _native.library("_ckernel")
        P = ctypes.POINTER
        lib.diffsurf_project.argtypes = [P(_Target), P(_Options), _I, F64, F64, _I, _I, _I,
                                         P(_Outputs)]
        lib.diffsurf_project.restype = ctypes.c_int
        lib.diffsurf_nearest_distances.argtypes = [F64, _I, F64, _D, I64, I64, I64, _I, F64]
        lib.diffsurf_nearest_distances.restype = ctypes.c_int
        lib.diffsurf_knn.argtypes = [F64, F64, _D, I64, I64, I64, F64, _I, I64, F64]
        lib.diffsurf_knn.restype = _I
        lib.diffsurf_ball.argtypes = [F64, F64, _D, I64, I64, I64, F64, _D, _I, I64, F64]
        lib.diffsurf_ball.restype = _I
        _LIB = lib
    return _LIB


class _Arrays:
    """Arrays handed to C: converted to contiguous arrays of the C type (kept alive here until
    the call returns), outputs written back into the caller's arrays if they had to be
    copied."""

    _CTYPES = {np.float64: _P64, np.int64: _PI64, np.int8: _PI8, np.uint8: _PU8}

    def __init__(self):
        self.keep = []
        self.back = []

    def input(self, a, dtype, shape=None):
        arr = np.ascontiguousarray(a, dtype=dtype)
        if arr.dtype == np.bool_:
            arr = arr.view(np.uint8)
        if shape is not None and arr.shape != tuple(shape):
            raise ValueError(f"kernel: an array of shape {arr.shape}, expected {tuple(shape)}")
        self.keep.append(arr)
        return arr.ctypes.data_as(self._CTYPES[arr.dtype.type])

    def output(self, a, dtype, shape):
        if a.shape != tuple(shape):
            raise ValueError(f"kernel: an output of shape {a.shape}, expected {tuple(shape)}")
        arr = a
        if a.dtype != dtype or not a.flags.c_contiguous or not a.flags.writeable:
            arr = np.empty(shape, dtype)
            self.back.append((a, arr))
        c = arr.view(np.uint8) if arr.dtype == np.bool_ else arr
        self.keep.append(c)
        return c.ctypes.data_as(self._CTYPES[c.dtype.type])

    def write_back(self):
        for a, arr in self.back:
            a[...] = arr


def _grid_arrays(coords, lo, cell, dims, start, order):
    """The arrays of a grid (build_grid) with the C types, checked against each other."""
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    lo = np.ascontiguousarray(lo, dtype=np.float64).reshape(3)
    dims = np.ascontiguousarray(dims, dtype=np.int64).reshape(3)
    start = np.ascontiguousarray(start, dtype=np.int64)
    order = np.ascontiguousarray(order, dtype=np.int64)
    if len(start) != int(np.prod(dims)) + 1 or len(order) != len(coords):
        raise ValueError("kernel: a grid whose arrays do not match (see build_grid)")
    return coords, lo, float(cell), dims, start, order


def _grid(arrays, *grid):
    coords, lo, cell, dims, start, order = _grid_arrays(*grid)
    return _Grid(arrays.input(coords, np.float64), arrays.input(lo, np.float64), cell,
                 arrays.input(dims, np.int64), arrays.input(start, np.int64),
                 arrays.input(order, np.int64))


# --------------------------------------------------------------------------------------------
# entry points
# --------------------------------------------------------------------------------------------


def project(nodes, normals, node_spacing, has_faces, first, duplicates,
            fold_normals, signed, steep, cos_fold,
            grid_lo, grid_cell, grid_dims, grid_start, grid_order,
            plane, plane_lo, plane_cell, plane_dims, plane_start, plane_order,
            frame_origin, frame_axes, global_frame,
            ea, eb, weight_code, knn, radius, k, frame_ball, knn_factor, sheet_cos,
            spacing_neighbours, rcond_min, contact_tol, outside_spacings, hull_spacings,
            consts,
            points, reference, centred, cap, threads,
            gap, normal, proximal, status, reason, support, iterations, rcond_out, curvature,
            origin_out, axes_out, radius_out, spacing_out, index_out, overflow):
    """Project `points` with supports selected around `reference` (see surface.py), on
    `threads` threads (0: all of OpenMP's).

    Writes the Projection fields and the pairing (origin, axes, R, h, support index padded
    with -1 to its width) into the output arrays; overflow[i] is set where the support had more
    than `cap` nodes (the caller retries those rows with a larger cap).
    """
    arr = _Arrays()
    nodes = np.ascontiguousarray(nodes, dtype=np.float64).reshape(-1, 3)
    n = len(nodes)
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    reference = np.ascontiguousarray(reference, dtype=np.float64).reshape(-1, 3)
    m = len(points)
    if len(reference) != m:
        raise ValueError("kernel: points and reference differ in length")
    ea = np.ascontiguousarray(ea, dtype=np.int64)
    eb = np.ascontiguousarray(eb, dtype=np.int64)
    cap, k, spacing_neighbours = int(cap), int(k), int(spacing_neighbours)
    if cap < 1 or (knn and not 1 <= k <= cap) or not 1 <= spacing_neighbours <= n:
        raise ValueError("kernel: cap, k or spacing_neighbours out of range")
    consts = np.ascontiguousarray(consts, dtype=np.float64)
    if consts.shape != constants().shape:
        raise ValueError("kernel: consts is not kernel.constants()")
    target = _Target(
        arr.input(nodes, np.float64), arr.input(normals, np.float64, (n, 3)),
        arr.input(node_spacing, np.float64, (n,)), arr.input(first, np.int64, (n,)),
        arr.input(fold_normals, np.float64, (n, 3)), arr.input(signed, np.bool_, (n,)),
        arr.input(steep, np.bool_, (n,)),
        _grid(arr, nodes, grid_lo, grid_cell, grid_dims, grid_start, grid_order),
        _grid(arr, plane, plane_lo, plane_cell, plane_dims, plane_start, plane_order),
        arr.input(frame_origin, np.float64, (3,)), arr.input(frame_axes, np.float64, (3, 3)),
        bool(has_faces), bool(duplicates), bool(global_frame))
    options = _Options(
        arr.input(ea, np.int64), arr.input(eb, np.int64, ea.shape), len(ea),
        int(weight_code), bool(knn), k, spacing_neighbours,
        float(radius), float(frame_ball), float(knn_factor), float(sheet_cos), float(cos_fold),
        float(rcond_min), float(contact_tol), float(outside_spacings), float(hull_spacings),
        arr.input(consts, np.float64))
    if index_out.ndim != 2:
        raise ValueError("kernel: index_out must be (m, width)")
    width = index_out.shape[1]
    out = _Outputs(
        arr.output(gap, np.float64, (m,)), arr.output(normal, np.float64, (m, 3)),
        arr.output(proximal, np.float64, (m, 3)), arr.output(status, np.int8, (m,)),
        arr.output(reason, np.int8, (m,)), arr.output(support, np.int64, (m,)),
        arr.output(iterations, np.int64, (m,)), arr.output(rcond_out, np.float64, (m,)),
        arr.output(curvature, np.float64, (m, 2)), arr.output(origin_out, np.float64, (m, 3)),
        arr.output(axes_out, np.float64, (m, 3, 3)), arr.output(radius_out, np.float64, (m,)),
        arr.output(spacing_out, np.float64, (m,)), arr.output(index_out, np.int64, (m, width)),
        width, arr.output(overflow, np.bool_, (m,)))
    if m == 0:
        return
    if _lib().diffsurf_project(ctypes.byref(target), ctypes.byref(options), m, points,
                               reference, bool(centred), cap, int(threads),
                               ctypes.byref(out)) != 0:
        raise MemoryError("kernel: no memory for the projection's scratch")
    arr.write_back()


def nearest_distances(coords: np.ndarray, k: int) -> np.ndarray:
    """Distances (n, k) from each of `coords` to its k nearest (itself first), nearest first:
    what scipy's ``cKDTree(coords).query(coords, k)`` gives, without importing scipy."""
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    k = int(k)
    out = np.empty((len(coords), k))
    if len(coords) == 0 or k == 0:
        return out
    span = float(np.ptp(coords, axis=0).max())
    # about k nodes per cell on a surface
    cell = span / max(np.sqrt(len(coords) / max(k, 1)), 1.0) if span > 0 else 1.0
    lo, cell, dims, start, order = build_grid(coords, cell)
    if _lib().diffsurf_nearest_distances(coords, len(coords), lo, cell, dims, start, order, k,
                                         out) != 0:
        raise MemoryError("kernel: no memory for the nearest-node search")
    return out


def _knn(coords, lo, cell, dims, start, order, p, k, best_i, best_d2):
    """The k nearest nodes of p on the grid (build_grid), nearest first, in best_i/best_d2
    (contiguous int64 / float64 of at least k entries); returns how many (≤ k)."""
    k = int(k)
    if not 1 <= k <= min(len(best_i), len(best_d2)):
        raise ValueError(f"kernel: k = {k} outside 1..{min(len(best_i), len(best_d2))}")
    grid = _grid_arrays(coords, lo, cell, dims, start, order)
    return int(_lib().diffsurf_knn(*grid, _point(p), k, best_i, best_d2))


def _ball(coords, lo, cell, dims, start, order, p, r, out_i, out_d2):
    """All nodes within r of p on the grid (build_grid), nearest first; returns their number
    (only the first len(out_i) are stored: a larger return value means the scratch was too
    small)."""
    cap = min(len(out_i), len(out_d2))
    grid = _grid_arrays(coords, lo, cell, dims, start, order)
    return int(_lib().diffsurf_ball(*grid, _point(p), float(r), cap, out_i, out_d2))


def _point(p):
    return np.ascontiguousarray(p, dtype=np.float64).reshape(3)
