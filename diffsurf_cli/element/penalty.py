"""The penalty ε of the penalty method [3]: the one check every element's residual, tangent
and assembly make of it (`element.Contact`, `element.rigid.RigidResult`, `assemble`)."""
from __future__ import annotations

import numpy as np


def check_penalty(penalty, name: str = "penalty") -> np.ndarray:
    """ε as a float array (a number, or one per contactor), refused (ValueError) unless every
    value is finite and > 0: a penalty of 0, below 0, NaN or inf is no spring (a negative one
    pulls the contactor in)."""
    eps = np.asarray(penalty, dtype=np.float64)
    bad = ~(np.isfinite(eps) & (eps > 0))
    if bad.any():
        first = eps.flat[int(np.flatnonzero(bad.ravel())[0])]
        where = "" if eps.ndim == 0 else f" (contactor {int(np.flatnonzero(bad.ravel())[0])})"
        raise ValueError(f"{name} must be finite and > 0, got {float(first)!r}{where}")
    return eps
