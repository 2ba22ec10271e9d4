# cython: language_level=3
"""The names and constants of the weights (`_weight.pxd`): what Python reads (WEIGHTS,
mls/weight.py's), and the constants every compiled module's weight takes from
diffsurf_cli.tol (`weight_params`)."""
import numpy as np

from .. import tol

#: The weights [15], by code (`_weight.pxd`): mls/weight.py's names.
WEIGHTS = tuple(name for _, name in sorted({
    WENDLAND: "wendland", GAUSS: "gauss", SINGULAR: "singular"}.items()))
#: name -> code
WEIGHT_CODES = {name: code for code, name in enumerate(WEIGHTS)}


cdef WeightParams weight_params(str name) except *:
    """The weight `name` (a KeyError if none) with its constants, from diffsurf_cli.tol: the
    truncated Gaussian's width² and its value at q = 1, the singular weight's floor of q."""
    cdef WeightParams wp
    wp.kind = WEIGHT_CODES[name]
    wp.gauss_c2 = tol.GAUSS_WIDTH**2
    wp.gauss_tail = np.exp(-1.0 / tol.GAUSS_WIDTH**2)
    wp.singular_floor = tol.SINGULAR_FLOOR
    return wp
