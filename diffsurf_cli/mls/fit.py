"""Weighted least-squares fit of the local approximation, [15]-[17].

Minimising J(α) = Σ w^i (p(X^i)ᵀ α - X3^i)² [15] gives (Pᵀ W P) α = Pᵀ W Z [17]. It is solved
here through the SVD of W^½ P (coordinates already scaled by R), which is backward stable even
for the singular interpolating weight, whose rows differ in scale by many orders, and which
gives the condition number for free.
"""
from __future__ import annotations

import numpy as np

from . import basis as _basis
from .. import tol


def fit(basis: str, s: np.ndarray, t: np.ndarray, z: np.ndarray, w: np.ndarray,
        geometry: np.ndarray | None = None):
    """Coefficients α of each local approximation.

    Parameters
    ----------
    basis : str
    s, t, z : (m, K) float
        Support node coordinates in the scaled frame (X - X^ref) / R.
    w : (m, K) float
        Weights w^i; 0 for padding and nodes outside the domain of influence.
    geometry : (m, K) float, optional
        Weights to judge the conditioning with instead of `w` (the fit still uses `w`).

    Returns
    -------
    alpha : (m, k) float
        NaN rows where the fit is impossible (rank-deficient support).
    rcond : (m,) float
        Reciprocal condition number σ_min/σ_max of W^½ P with equilibrated columns (0 when
        rank-deficient).
    """
    P = _basis.evaluate(basis, s, t)  # (m, K, k) [20]
    k = P.shape[-1]
    if P.shape[1] < k:  # fewer candidate nodes than terms in every row: pad to keep shapes
        pad = k - P.shape[1]
        P = np.pad(P, ((0, 0), (0, pad), (0, 0)))
        z = np.pad(z, ((0, 0), (0, pad)))
        w = np.pad(w, ((0, 0), (0, pad)))
        if geometry is not None:
            geometry = np.pad(geometry, ((0, 0), (0, pad)))
    # normalise each row's weights (α does not depend on a common factor) and equilibrate the
    # columns (solve for D α): the condition number then measures the support's geometry, not
    # the scale of the basis terms, so one threshold serves every basis
    with np.errstate(invalid="ignore", over="ignore"):
        B = _rows(w)[..., None] * P
        scale = _column_scale(B)  # (m, k)
        A = B / scale[:, None, :]
    # rows whose coordinates overflowed (a contactor ~1e154 away) cannot be fitted: zeroed so
    # the SVD runs, then rcond 0 and α NaN
    broken = ~np.all(np.isfinite(A), axis=(1, 2))
    A[broken] = 0.0
    u, sig, vt = np.linalg.svd(A, full_matrices=False)
    rcond = _rcond(sig)
    if geometry is not None:
        with np.errstate(invalid="ignore", over="ignore"):
            G = _rows(geometry)[..., None] * P
            G = G / _column_scale(G)[:, None, :]
        G[~np.all(np.isfinite(G), axis=(1, 2))] = 0.0
        rcond = _rcond(np.linalg.svd(G, compute_uv=False))
    rcond[broken] = 0.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        coef = np.einsum("mKk,mK->mk", u, _rows(w) * z) / sig
        alpha = np.einsum("mkj,mk->mj", vt, coef) / scale
    alpha[~(rcond > 0) | ~np.all(np.isfinite(alpha), axis=1)] = np.nan
    return alpha, rcond


def _column_scale(B: np.ndarray) -> np.ndarray:
    """Column norms (m, k) of B (m, K, k) for equilibration, floored at
    `tol.EQUILIBRATION_FLOOR` times the row's largest: a column of round-off (t ~ 1e-17 when
    the support lies on a line) must stay negligible, not be blown up to a unit column that
    looks independent of the others."""
    scale = np.linalg.norm(B, axis=1)
    scale = np.maximum(scale, tol.EQUILIBRATION_FLOOR * scale.max(axis=1, keepdims=True))
    return np.where(scale > 0, scale, 1.0)


def _rcond(sig: np.ndarray) -> np.ndarray:
    top = sig[:, 0]
    return np.where(top > 0, sig[:, -1] / np.where(top > 0, top, 1.0), 0.0)


def _rows(w: np.ndarray) -> np.ndarray:
    """Square roots of each row's weights, normalised so the largest is 1."""
    top = w.max(axis=1, keepdims=True)
    return np.sqrt(w / np.where(top > 0, top, 1.0))
