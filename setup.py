"""Build of diffsurf's compiled engine (the rest of the metadata is in pyproject.toml).

Cython extension modules, compiled by ``pip install`` (or ``python -m build``):

- ``diffsurf_cli.mls._linalg``, ``_search``, ``_weight``, ``_projection``: the projection onto
  the diffuse surface [§3-§4.1] (small dense linear algebra, the support search, the weights'
  names and constants, the pass; its steps are ``cdef inline`` in the .pxd files beside it);
- ``diffsurf_cli.facet._engine``: the closest point on the facets (node-to-facet, §2), and
  ``facet._setup`` the facets' tables;
- ``diffsurf_cli.patches._pass``: the default surface's pass (patches, guard, curved cells),
  and its setup: ``_topology`` (node identity, edges, segmentation, facet rings), ``_guard``
  (corner normals, the guard's bounds), ``_cells`` (curved cells), ``_clearance`` (thin walls),
  ``_edges`` (the edges' cosines and classes, flat faces);
- ``diffsurf_cli.element._element``: the diffuse contact element (g, 𝒩, ℳ) [§4.2-4.3];
- ``diffsurf_cli.element._assembly``: the contact tangent summed into CSR;
- ``diffsurf_cli.element._rigid``: the closest point on a rigid target's fixed surface;
- ``diffsurf_cli._codes``: the status and reason codes shared by all of them.

Their interfaces are typed memoryviews checked by the compiler; their small dense linear
algebra (Householder QR, Jacobi) is written from Golub & Van Loan's textbook descriptions;
loops over contactors run in parallel with OpenMP (``prange``) where the compiler has it.
"""
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

NEEDS_COMPILER = ("diffsurf: a C compiler is needed to build diffsurf's compiled engine "
                  "(install gcc or clang, or MSVC Build Tools on Windows), or install a wheel")

if sys.platform == "win32":
    CFLAGS, LDFLAGS = ["/O2", "/openmp"], []
elif sys.platform == "darwin":
    CFLAGS, LDFLAGS = ["-O3", "-fno-math-errno"], []
else:
    CFLAGS, LDFLAGS = ["-O3", "-fopenmp", "-fno-math-errno"], ["-fopenmp"]


class BuildExt(build_ext):
    """build_ext that says in one line that a C compiler is missing, instead of a traceback."""

    def run(self):
        from setuptools._distutils.errors import (
            CCompilerError,
            CompileError,
            DistutilsExecError,
            DistutilsPlatformError,
        )
        try:
            super().run()
        except (CCompilerError, CompileError, DistutilsExecError, DistutilsPlatformError) as exc:
            raise SystemExit(f"{NEEDS_COMPILER} ({exc})") from None

    def build_extensions(self):
        if not _has_compiler(self.compiler):
            raise SystemExit(NEEDS_COMPILER)
        super().build_extensions()


def _has_compiler(compiler) -> bool:
    """Whether the configured C compiler runs at all (an empty translation unit compiles)."""
    import os
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "probe.c")
        with open(src, "w") as fh:
            fh.write("int main(void) { return 0; }\n")
        try:
            compiler.compile([src], output_dir=tmp)
        except Exception:  # noqa: BLE001 - any failure of the probe means no usable compiler
            return False
    return True


def _libomp() -> str | None:
    """The prefix of LLVM's OpenMP runtime on macOS (Apple clang has none of its own): the
    DIFFSURF_LIBOMP variable, else Homebrew's libomp; None (the engine then runs on one
    thread) without either."""
    import os
    import subprocess

    prefix = os.environ.get("DIFFSURF_LIBOMP")
    if not prefix:
        try:
            prefix = subprocess.run(["brew", "--prefix", "libomp"], capture_output=True,
                                    text=True, check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            prefix = None
    if prefix and os.path.exists(os.path.join(prefix, "include", "omp.h")):
        return prefix
    return None


if sys.platform == "darwin":
    _OMP = _libomp()
    if _OMP is not None:  # clang's OpenMP through the preprocessor, linked to libomp (the
        # wheel repair, delocate, copies libomp.dylib into the wheel)
        CFLAGS += ["-Xpreprocessor", "-fopenmp", f"-I{_OMP}/include"]
        LDFLAGS += [f"-L{_OMP}/lib", "-lomp", f"-Wl,-rpath,{_OMP}/lib"]


def _extensions():
    from Cython.Build import cythonize

    exts = [Extension(name, [path], extra_compile_args=CFLAGS, extra_link_args=LDFLAGS)
            for name, path in (("diffsurf_cli._codes", "diffsurf_cli/_codes.pyx"),
                               ("diffsurf_cli.mls._linalg", "diffsurf_cli/mls/_linalg.pyx"),
                               ("diffsurf_cli.mls._search", "diffsurf_cli/mls/_search.pyx"),
                               ("diffsurf_cli.mls._weight", "diffsurf_cli/mls/_weight.pyx"),
                               ("diffsurf_cli.mls._projection", "diffsurf_cli/mls/_projection.pyx"),
                               ("diffsurf_cli.mls._quadric", "diffsurf_cli/mls/_quadric.pyx"),
                               ("diffsurf_cli.facet._engine", "diffsurf_cli/facet/_engine.pyx"),
                               ("diffsurf_cli.facet._setup", "diffsurf_cli/facet/_setup.pyx"),
                               ("diffsurf_cli.patches._pass", "diffsurf_cli/patches/_pass.pyx"),
                               ("diffsurf_cli.patches._guard", "diffsurf_cli/patches/_guard.pyx"),
                               ("diffsurf_cli.patches._clearance",
                                "diffsurf_cli/patches/_clearance.pyx"),
                               ("diffsurf_cli.patches._topology",
                                "diffsurf_cli/patches/_topology.pyx"),
                               ("diffsurf_cli.patches._cells", "diffsurf_cli/patches/_cells.pyx"),
                               ("diffsurf_cli.patches._edges", "diffsurf_cli/patches/_edges.pyx"),
                               ("diffsurf_cli.element._element",
                                "diffsurf_cli/element/_element.pyx"),
                               ("diffsurf_cli.element._assembly",
                                "diffsurf_cli/element/_assembly.pyx"),
                               ("diffsurf_cli.element._rigid", "diffsurf_cli/element/_rigid.pyx"))]
    return cythonize(exts, language_level=3, compiler_directives={
        "boundscheck": False, "wraparound": False, "cdivision": True,
        "initializedcheck": False})


setup(ext_modules=_extensions(), cmdclass={"build_ext": BuildExt})
