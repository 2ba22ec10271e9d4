"""Build of the two compiled parts of diffsurf (the rest of the metadata is in pyproject.toml).

Both are plain C (C99, OpenMP), loaded with ctypes: no Python or numpy headers are needed, and
nothing is compiled at run time. They replaced numba kernels, whose per-process start-up
(0.7 s: import, type registries, cache loading) was longer than the whole projection of 200k
points, and whose first run after installing compiled for 30 s (benchmarks/compare.py).
"""
import sys

from setuptools import Extension, setup

if sys.platform == "win32":
    _CFLAGS, _LDFLAGS = ["/O2", "/openmp", "/fp:precise"], []
elif sys.platform == "darwin":  # Apple clang has no -fopenmp: serial there
    _CFLAGS, _LDFLAGS = ["-O3", "-std=c99", "-ffp-contract=off"], []
else:
    # -ffp-contract=off: no fused multiply-add, so results match the numpy reference's rounding
    _CFLAGS = ["-O3", "-std=c99", "-fopenmp", "-ffp-contract=off", "-fno-math-errno"]
    _LDFLAGS = ["-fopenmp"]


def _extension(name):
    return Extension(f"diffsurf_cli.{name}", [f"diffsurf_cli/{name}.c"],
                     extra_compile_args=_CFLAGS, extra_link_args=_LDFLAGS)


setup(ext_modules=[_extension("_ckernel"), _extension("_ccsv")])
