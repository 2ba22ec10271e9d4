"""Outputs and inputs of the contact element: frozen pairings (.npz) and Matrix Market
matrices (.mtx), and the translation of pairings and elements between the core's terms
(surface node indices, `Patch`) and the files' (the target file's point indices)."""
from __future__ import annotations

import numpy as np

from .atomic import write_atomically
from .errors import REASON_CHARS, ReadError, first_line, os_reason
from .paths import check_input_file, check_output_path

__all__ = ["save_pairs", "load_pairs", "write_matrix", "save_elements", "pairing_from_core",
           "pairing_to_core", "elements_from_core"]

#: arrays a stored pairing holds, per method.
_PAIR_ARRAYS = {"diffuse": ("origin", "axes", "radius", "spacing", "index"), "facet": ("facet",)}


def write_matrix(path: str, matrix, overwrite: bool = False, comment: str = "") -> None:
    """Write a dense (n, 1) vector or a sparse matrix in Matrix Market format, atomically.

    scipy.io.mmread and FE codes read it back; values keep full precision.
    """
    import scipy.io

    path = str(path)
    check_output_path(path, overwrite, kind="matrix")
    def write(tmp):
        # through a Python file: given a file name, scipy's writer (fast_matrix_market) leaves
        # a truncated file and no error when the disk is full
        with open(tmp, "wb") as fh:
            scipy.io.mmwrite(fh, matrix, comment=comment, precision=17)

    write_atomically(path, overwrite, ".mtx", write)


def save_pairs(path: str, pairing: dict, overwrite: bool = False) -> None:
    """Store a frozen pairing (``method``, counts and the method's arrays) as .npz, atomically."""
    _save_npz(path, pairing, overwrite)


def save_elements(path: str, arrays: dict, overwrite: bool = False) -> None:
    """Store the contact element arrays (``contact``, ``nodes``, ``gap``, ``N``, ``M``,
    ``status``, ...) as .npz (np.savez, no pickled objects), atomically."""
    _save_npz(path, arrays, overwrite)


def _save_npz(path: str, pairing: dict, overwrite: bool) -> None:
    path = str(path)
    check_output_path(path, overwrite, kind="pairs")
    arrays = {k: np.asarray(v) for k, v in pairing.items()}

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    write_atomically(path, overwrite, ".npz", write)


def load_pairs(path: str, *, method: str, n_contactors: int, n_target: int) -> dict:
    """Read a pairing stored by :func:`save_pairs` and check it matches the inputs.

    Raises ReadError when the file is not a pairing (not an .npz archive, arrays missing or of
    the wrong type or shape, non-finite frames or radii), was made with another method, was
    made for other counts of contactors or target points, or refers to target points that do
    not exist. The facet indices of a ``facet`` pairing are only checked to be >= -1 here: the
    number of facets is known to the caller.
    """
    path = str(path)
    check_input_file(path)
    expected = "expected a pairing file written by --save-pairs"
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ReadError(f"{path}: cannot read ({os_reason(exc)})") from None
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):  # every .npz is a zip archive
        raise ReadError(f"{path}: not an .npz archive, {expected}")
    try:
        with np.load(path, allow_pickle=False) as data:
            pairing = {k: data[k] for k in data.files}
    except Exception as exc:  # noqa: BLE001 - any failure here means "not a pairing file"
        raise ReadError(f"{path}: unreadable .npz archive ({first_line(exc)[:REASON_CHARS]}), "
                        f"{expected}") from None
    stored = pairing.get("method")
    if stored is None or stored.shape != () or stored.dtype.kind != "U" \
            or str(stored) not in _PAIR_ARRAYS:
        raise ReadError(f"{path}: no pairing method (diffuse or facet) stored, {expected}")
    stored = str(stored)
    missing = [k for k in ("n_contactors", "n_target") + _PAIR_ARRAYS[stored] if k not in pairing]
    if missing:
        raise ReadError(f"{path}: no '{missing[0]}' array, {expected}")
    if stored != method:
        raise ReadError(f"{path}: pairing made with --method {stored}, not {method}")
    for key in ("n_contactors", "n_target"):
        if pairing[key].shape != () or pairing[key].dtype.kind not in "iu":
            raise ReadError(f"{path}: '{key}' is not a count, {expected}")
    counts = (int(pairing["n_contactors"]), int(pairing["n_target"]))
    if counts != (n_contactors, n_target):
        raise ReadError(
            f"{path}: pairing made for {counts[0]} contactors and {counts[1]} target points, "
            f"the inputs have {n_contactors} and {n_target}")
    p = n_contactors
    shapes = {"origin": (p, 3), "axes": (p, 3, 3), "radius": (p,), "spacing": (p,),
              "index": (p, None), "facet": (p,)}
    for key in _PAIR_ARRAYS[stored]:
        arr, shape = pairing[key], shapes[key]
        integer = key in ("index", "facet")
        wrong_shape = arr.ndim != len(shape) or any(n is not None and n != m
                                                    for n, m in zip(shape, arr.shape))
        if wrong_shape or arr.dtype.kind not in ("iu" if integer else "f"):
            want = "x".join("k" if n is None else str(n) for n in shape)
            raise ReadError(f"{path}: '{key}' is {arr.dtype} of shape {arr.shape}, expected "
                            f"{'integers' if integer else 'floats'} of shape ({want}); "
                            f"{expected}")
        if not integer and not np.isfinite(arr).all():
            raise ReadError(f"{path}: '{key}' holds NaN or inf, {expected}")
        if integer and arr.min(initial=-1) < -1:
            raise ReadError(f"{path}: '{key}' holds negative indices, {expected}")
    if stored == "diffuse" and pairing["index"].max(initial=-1) >= n_target:
        raise ReadError(f"{path}: pairing refers to target points that do not exist")
    # optional (a strip's reduced basis and its direction; absent from older files, then the
    # projection chooses them again)
    for key, kind in (("reduced", "iu"), ("direction", "f")):
        if stored == "diffuse" and key in pairing:
            arr = pairing[key]
            if arr.shape != (p,) or arr.dtype.kind not in kind \
                    or (kind == "iu" and arr.min(initial=-1) < -1):
                raise ReadError(f"{path}: '{key}' is {arr.dtype} of shape {arr.shape}, "
                                f"{expected}")
    return pairing


def pairing_from_core(projection, target, method: str) -> dict:
    """A projection's frozen pairing in file terms, for `save_pairs`.

    Parameters
    ----------
    projection : Projection
        Of ``surface.project(points, keep_patch=True)`` (diffuse: its ``patch``) or of a
        `FacetSurface` (its ``facet``).
    target : Target
        The target file the surface was built from (`read_target`): surface node i is its
        point ``target.nodes[i]``.
    method : {'diffuse', 'facet'}

    Returns
    -------
    dict
        ``method``, ``n_contactors``, ``n_target`` and, diffuse: ``origin`` (m, 3), ``axes``
        (m, 3, 3), ``radius`` (m,), ``spacing`` (m,), ``index`` (m, K) (target file point
        indices, -1 padded) and, where known, ``reduced`` (m,), ``direction`` (m,); facet:
        ``facet`` (m,).
    """
    meta = {"method": method, "n_contactors": len(projection.points),
            "n_target": len(target.points)}
    if method == "facet":
        return {**meta, "facet": projection.facet}
    p = projection.patch
    index = np.where(p.index >= 0, target.nodes[np.maximum(p.index, 0)], -1)
    extra = ({} if p.reduced is None or p.direction is None
             else {"reduced": p.reduced, "direction": p.direction})
    return {**meta, "origin": p.origin, "axes": p.axes, "radius": p.radius,
            "spacing": p.spacing, "index": index, **extra}


def pairing_to_core(pairing: dict, target, method: str, surface, path: str):
    """A pairing read by `load_pairs` in the core's terms: the ``pairing=`` of `contact` and
    the argument of ``surface.project_with``.

    Parameters
    ----------
    pairing : dict
        As `load_pairs` returns it.
    target : Target
        The target file the surface was built from.
    method : {'diffuse', 'facet'}
    surface : DiffuseSurface or FacetSurface
    path : str
        The pairing file, for the messages.

    Returns
    -------
    Patch (diffuse: support indices into the surface's nodes) or (m,) int (facet: indices into
    ``surface.facets``)

    Raises
    ------
    ReadError
        The pairing's support nodes or facets are not those of this target (another mesh or
        zone).
    """
    from ..projection import Patch

    if method == "facet":
        if pairing["facet"].max(initial=-1) >= len(surface.facets):
            raise ReadError(f"{path}: the pairing's facets are not facets of the target "
                            f"(other mesh or zone?)")
        return pairing["facet"]
    idx = pairing["index"]
    local = np.searchsorted(target.nodes, np.maximum(idx, 0))
    local = np.minimum(local, len(target.nodes) - 1)
    ok = (idx < 0) | (target.nodes[local] == idx)
    if not ok.all():
        raise ReadError(f"{path}: the pairing's support nodes are not surface nodes of the "
                        f"target (other mesh or zone?)")
    return Patch(pairing["origin"], pairing["axes"], pairing["radius"], pairing["spacing"],
                 np.where(idx >= 0, local, -1), pairing.get("reduced"), pairing.get("direction"))


def elements_from_core(result, target, method: str) -> dict:
    """The contact element arrays in file terms, for `save_elements`.

    Parameters
    ----------
    result : Contact
        Of `contact`.
    target : Target
        The target file the surface was built from.
    method : {'diffuse', 'facet'}

    Returns
    -------
    dict
        ``contactor`` (e,), ``nodes`` (e, K) (target file point indices, -1 padded), ``gap``
        (e,), ``N`` (e, 3(K+1)), ``M`` (e, 3(K+1), 3(K+1)), ``status`` and ``reason`` (m,), their
        words ``status_names`` and ``reason_names``, ``rigid_target`` and ``method``.
    """
    from ..projection import REASONS, STATUS

    nodes = np.where(result.nodes >= 0, target.nodes[np.maximum(result.nodes, 0)], -1)
    return {"contactor": result.contactor, "nodes": nodes, "gap": result.gap, "N": result.N,
            "M": result.M, "status": result.status, "reason": result.reason,
            "status_names": np.array(STATUS), "reason_names": np.array(REASONS),
            "rigid_target": np.array(result.rigid_target), "method": np.array(method)}
