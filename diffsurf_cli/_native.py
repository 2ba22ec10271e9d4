"""The compiled parts of diffsurf (_ckernel.c, _ccsv.c), loaded with ctypes.

They are built by ``pip install`` (setup.py) as extension files next to this module; ctypes
calls release the GIL, and OpenMP runs their loops on every core (``OMP_NUM_THREADS`` caps it).
"""
from __future__ import annotations

import ctypes
import importlib.machinery
import os
from pathlib import Path

import numpy as np

_HERE = Path(__file__).resolve().parent
_LOADED: dict[str, ctypes.CDLL] = {}

#: ctypes argument types
F64 = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
I64 = np.ctypeslib.ndpointer(dtype=np.int64, flags="C_CONTIGUOUS")
I8 = np.ctypeslib.ndpointer(dtype=np.int8, flags="C_CONTIGUOUS")
U8 = np.ctypeslib.ndpointer(dtype=np.uint8, flags="C_CONTIGUOUS")
U64 = np.ctypeslib.ndpointer(dtype=np.uint64, flags="C_CONTIGUOUS")


class NotBuilt(ImportError):
    """The compiled library is missing (diffsurf was not installed with pip)."""


def library(name: str) -> ctypes.CDLL:
    """The compiled library `name` ('_ckernel' or '_ccsv'), loaded once."""
    if name not in _LOADED:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = _HERE / f"{name}{suffix}"
            if path.exists():
                _LOADED[name] = ctypes.CDLL(os.fspath(path))
                break
        else:
            raise NotBuilt(f"diffsurf's compiled {name} is not built: install diffsurf with "
                           f"pip (`pip install .` or `pip install -e .`), which compiles it")
    return _LOADED[name]


def threads() -> int:
    """Threads the compiled loops use (OpenMP's, capped by OMP_NUM_THREADS)."""
    return int(library("_ckernel").diffsurf_threads())
