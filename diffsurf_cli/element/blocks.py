"""ℳ built on demand, a block of elements at a time: what bounds a `Contact`'s memory
whatever its number of elements (issue 21). Every element kind (diffuse, node-to-facet,
node-to-cell) hands its ℳ to a `Hessians` past `HESSIAN_BYTES`, and `Contact.tangent`
assembles `TANGENT_BATCH` entries at a time; both limits live here alone, and are read at
each call."""
from __future__ import annotations

import contextlib
import contextvars

import numpy as np

#: Entries of the element tangents built at once by `Contact.tangent` (≈ 50 MB of COO
#: values and indices): bounds its memory whatever the number of elements. Where ℳ is
#: built and added at once (`Hessians.tangent`), a call takes TANGENT_BATCH / (4 w) elements
#: (w = 3(K+1)): their inputs (𝒩, nodes, pairing), about 4 w numbers each.
TANGENT_BATCH = 1_000_000

#: Bytes of ℳ a `Contact` holds whole; beyond, its ℳ is built on demand, a block of elements
#: at a time (`Hessians`): 20,000 diffuse elements of 19 support nodes would hold 576 MB.
HESSIAN_BYTES = 64 * 2**20


class Hessians:
    """ℳ of a Contact's elements, built on demand from their frozen pairing (bitwise the
    numbers the whole array would hold): indexing by an element, a slice or indices builds
    those elements' ℳ only; `np.asarray` builds them all, in blocks.

    build(idx, out) -> (len(idx), w, w) ℳ of elements idx (w <= width; padded here with
    zeros); `out` (len(idx), width, width) or None: where it may write them (and return it).

    tangent(idx, nodes, ids, N, eps, p, lam, dT, places), optional: adds the tangent blocks
    eps 𝒩𝒩ᵀ + p ℳ (+ λ's and friction's terms) of elements idx into a CSR pattern's values,
    each ℳ built and added at once from the same numbers `build` gives
    (`diffuse.diffuse_tangent`): what `Contact.tangent` calls instead of `build`, where given.
    """

    def __init__(self, build, count: int, width: int, tangent=None):
        self._build = build
        self.tangent = tangent
        self.shape = (int(count), int(width), int(width))
        self.dtype = np.dtype(np.float64)
        self.ndim = 3

    def __len__(self) -> int:
        return self.shape[0]

    def take(self, idx, out=None) -> np.ndarray:
        """ℳ of elements idx (len(idx), width, width), into `out` if given."""
        idx = np.asarray(idx, dtype=np.int64).reshape(-1)
        if out is None:
            out = np.empty((len(idx),) + self.shape[1:])
        if not len(idx):
            return out
        block = self._build(idx, out)
        if block is not out:  # narrower elements: zero padding
            w = block.shape[1]
            out[:, :w, :w] = block
            out[:, w:] = 0.0
            out[:, :w, w:] = 0.0
        return out

    def __getitem__(self, key):
        if isinstance(key, (int, np.integer)):
            return self.take([range(self.shape[0])[key]])[0]
        if isinstance(key, slice):
            return self.take(np.arange(self.shape[0])[key])
        key = np.asarray(key)
        if key.dtype == bool:
            key = np.flatnonzero(key)
        return self.take(key)

    def subset(self, idx) -> Hessians:
        """The ℳ of elements idx, still built on demand."""
        idx = np.asarray(idx, dtype=np.int64).reshape(-1)
        tangent = (None if self.tangent is None else
                   lambda sub, *args: self.tangent(idx[sub], *args))
        return Hessians(lambda sub, out: self._build(idx[sub], out), len(idx), self.shape[1],
                        tangent)

    def __array__(self, dtype=None, copy=None):
        out = np.empty(self.shape)
        step = max(1, TANGENT_BATCH // max(1, self.shape[1] * self.shape[2]))
        for lo in range(0, self.shape[0], step):
            self.take(np.arange(lo, min(lo + step, self.shape[0])), out[lo:lo + step])
        return out if dtype is None else out.astype(dtype)


def rows_of(M, keep):
    """ℳ of the elements `keep` (a mask): None, an array's rows, or a `Hessians` subset."""
    if M is None:
        return None
    return M.subset(np.flatnonzero(keep)) if isinstance(M, Hessians) else M[keep]


def on_demand(count: int, width: int, second: bool) -> bool:
    """Whether `count` elements' ℳ (width x width) are built on demand (`HESSIAN_BYTES`, or
    always within `always_on_demand`)."""
    return second and (_ALWAYS.get() or count * width * width * 8 > HESSIAN_BYTES)


_ALWAYS = contextvars.ContextVar("diffsurf_hessians_on_demand", default=False)


@contextlib.contextmanager
def always_on_demand():
    """Within it, every Contact's ℳ is built on demand, whatever its size: `assemble`'s second
    pass, whose tangent then adds each element's ℳ as it is built and never holds a chunk's
    (a context variable: other threads are not affected)."""
    token = _ALWAYS.set(True)
    try:
        yield
    finally:
        _ALWAYS.reset(token)
