"""The oracle of `mls._search.build_tree` (issue 36): the former compiled code's quickselect,
line for line in Python (it read the coordinates through perm; the compiled code now swaps a
copy of them with perm). Small inputs only: tests/test_tree_fast.py."""
from __future__ import annotations

import numpy as np


def _dmin(a, b):
    return b if b < a else a


def _dmax(a, b):
    return b if b > a else a


def build_tree(coords, leaf=8):
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    n = len(coords)
    depth = 0
    while (n + (1 << depth) - 1) >> depth > leaf:
        depth += 1
    count = (2 << depth) - 1
    box = np.empty((count, 6))
    span = np.empty((count, 2), dtype=np.int64)
    perm = np.arange(n, dtype=np.int64)
    x = coords.tolist()
    span[0] = 0, n
    for level in range(depth + 1):
        first = (1 << level) - 1
        for t in range(first, 2 * first + 1):
            lo, hi = int(span[t, 0]), int(span[t, 1])
            b = [np.inf] * 3 + [-np.inf] * 3
            for i in range(lo, hi):
                for e in range(3):
                    v = x[perm[i]][e]
                    b[e] = _dmin(b[e], v)
                    b[3 + e] = _dmax(b[3 + e], v)
            box[t] = b
            if level == depth:
                continue
            ax = 0
            ext = b[3] - b[0]
            for e in range(1, 3):
                if b[3 + e] - b[e] > ext:
                    ext = b[3 + e] - b[e]
                    ax = e
            mid = lo + (hi - lo) // 2
            a, bb = lo, hi - 1
            while a < bb:
                pivot = x[perm[(a + bb) // 2]][ax]
                i, j = a, bb
                while i <= j:
                    while x[perm[i]][ax] < pivot:
                        i += 1
                    while x[perm[j]][ax] > pivot:
                        j -= 1
                    if i <= j:
                        perm[i], perm[j] = perm[j], perm[i]
                        i += 1
                        j -= 1
                if mid <= j:
                    bb = j
                elif mid >= i:
                    a = i
                else:
                    break
            span[2 * t + 1] = lo, mid
            span[2 * t + 2] = mid, hi
    return box, span, perm
