"""Weighted least-squares fit of the local approximation, [15]-[17].

Minimising J(α) = Σ w^i (p(X^i)ᵀ α - X3^i)² [15] gives (Pᵀ W P) α = Pᵀ W Z [17]. It is solved
here through the SVD of W^½ P (coordinates already scaled by R), which is backward stable even
for the singular interpolating weight, whose rows differ in scale by many orders, and which
gives the condition number for free.
"""
from __future__ import annotations

import numpy as np

from . import basis as _basis


def fit(basis: str, s: np.ndarray, t: np.ndarray, z: np.ndarray, w: np.ndarray):
    """Coefficients α of each local approximation.

    Parameters
    ----------
    basis : str
    s, t, z : (m, K) float
        Support node coordinates in the scaled frame (X - X^ref) / R.
    w : (m, K) float
        Weights w^i; 0 for padding and nodes outside the domain of influence.

    Returns
    -------
    alpha : (m, k) float
        NaN rows where the fit is impossible (rank-deficient support).
    rcond : (m,) float
        Reciprocal condition number σ_min/σ_max of W^½ P (0 when rank-deficient).
    """
    P = _basis.evaluate(basis, s, t)  # (m, K, k) [20]
    k = P.shape[-1]
    m = len(s)
    if P.shape[1] < k:  # fewer candidate nodes than terms in every row: pad to keep shapes
        pad = k - P.shape[1]
        P = np.pad(P, ((0, 0), (0, pad), (0, 0)))
        z = np.pad(z, ((0, 0), (0, pad)))
        w = np.pad(w, ((0, 0), (0, pad)))
    # normalise each row's weights: α does not depend on a common factor, conditioning does
    wmax = w.max(axis=1, keepdims=True)
    rw = np.sqrt(w / np.where(wmax > 0, wmax, 1.0))
    B = rw[..., None] * P
    u, sig, vt = np.linalg.svd(B, full_matrices=False)
    rcond = np.where(sig[:, 0] > 0, sig[:, -1] / np.where(sig[:, 0] > 0, sig[:, 0], 1.0), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        coef = np.einsum("mKk,mK->mk", u, rw * z) / sig
        alpha = np.einsum("mkj,mk->mj", vt, coef)
    alpha[~(rcond > 0) | ~np.all(np.isfinite(alpha), axis=1)] = np.nan
    return alpha, rcond
