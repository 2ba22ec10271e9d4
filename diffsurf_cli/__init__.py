"""diffsurf: diffuse (moving least squares) smoothing of faceted contact surfaces.

The numerical core works on numpy arrays only and imports neither click nor meshio:

- ``diffsurf_cli.projection``: what every surface answers with (`Projection`, the frozen
  pairing `Patch`, the status and reason codes);
- ``diffsurf_cli.mls``: the method of the paper [§3-§4.1]: basis, weight, frame, support, fit,
  projection, and `DiffuseSurface`, whose projection runs in the compiled engine; and
  `QuadricSurface`, quadrics fitted to positions and normals for coarse curved targets;
- ``diffsurf_cli.facet``: the faceted target itself (`FacetSurface`), the node-to-facet
  baseline [§2];
- ``diffsurf_cli.patches``: a target with sharp edges and flat faces as smooth patches
  (`PatchedSurface`: a `DiffuseSurface` per patch, the facets at sharp edges);
- ``diffsurf_cli.element``: the contact elements, diffuse and node-to-facet [§2, §4.2-4.3];
- ``diffsurf_cli.io``: the one package that touches files (meshes, tables, atomic writes);
- ``diffsurf_cli.presets``: the engine options, their defaults and the named presets;
- ``diffsurf_cli.targets``: a target's surface from a mesh file, with its method, preset and
  options, as the command line builds it (`surface_from_file`);
- ``diffsurf_cli.smooth``, ``diffsurf_cli.tune``, ``diffsurf_cli.cluster``: resampling a
  target, choosing a preset, projecting on a Dask cluster;
- ``diffsurf_cli.testing``: scenes with exact answers for the tests, benchmarks and examples
  (not the core API);
- ``diffsurf_cli.cli``: the thin command-line layer, one module per command; nothing else
  imports it.

The public API is importable from here::

    from diffsurf_cli import (DiffuseSurface, FacetSurface, assemble, contact, read_contactors,
                              read_target, surface_from_file)
    target, surface = surface_from_file("target.msh", preset="fast")  # as `diffsurf project`
"""
import os as _os

__version__ = "0.1.0"

#: OpenMP's idle threads (GNU libgomp, which Linux builds and wheels use) sleep at once instead
#: of spinning, unless the user chose (OMP_WAIT_POLICY or GOMP_SPINCOUNT in the environment):
#: libgomp's default spins 300,000 times (about 9 ms here) after every parallel region, so a
#: solver's `contact()` calls kept a second CPU busy between them (+45% CPU at 1,000
#: contactors), and on a machine whose other CPU was taken a spinning thread waited for its
#: turn at every region (7-12 ms each). Asleep, it costs a wake-up per region (15-50 µs here),
#: which every region pays anyway after a solver's own work; `tol.PARALLEL_MIN` only opens a
#: region where that pays (benchmarks/results/patch_speed.txt). libgomp reads it once, when it
#: is loaded: here, before any compiled module (an OpenMP runtime another package loaded
#: first keeps its own setting).
SPINCOUNT = "0"
if "OMP_WAIT_POLICY" not in _os.environ and "GOMP_SPINCOUNT" not in _os.environ:
    _os.environ["GOMP_SPINCOUNT"] = SPINCOUNT

# name -> module that defines it; imported on first use, so `import diffsurf_cli` (and the
# command line's start-up) does not pay for scipy.sparse or meshio unless they are used
_PUBLIC = {
    "DiffuseSurface": "diffsurf_cli.mls.surface",
    "QuadricSurface": "diffsurf_cli.mls.quadric",
    "PatchedSurface": "diffsurf_cli.patches.surface",
    "Projection": "diffsurf_cli.projection",
    "Surface": "diffsurf_cli.projection",
    "Patch": "diffsurf_cli.projection",
    "Pairing": "diffsurf_cli.projection",
    "STATUS": "diffsurf_cli.projection",
    "REASONS": "diffsurf_cli.projection",
    "FacetSurface": "diffsurf_cli.facet.surface",
    "RigidTarget": "diffsurf_cli.element.rigid",
    "RigidResult": "diffsurf_cli.element.rigid",
    "contact": "diffsurf_cli.element.element",
    "assemble": "diffsurf_cli.element.element",
    "Contact": "diffsurf_cli.element.element",
    "Coulomb": "diffsurf_cli.element.friction",
    "History": "diffsurf_cli.element.friction",
    "read_surface": "diffsurf_cli.targets",
    "build_surface": "diffsurf_cli.targets",
    "surface_from_file": "diffsurf_cli.targets",
    "coincident": "diffsurf_cli.targets",
    "outward_faces": "diffsurf_cli.targets",
    "wound_inward": "diffsurf_cli.targets",
    "PRESETS": "diffsurf_cli.presets",
    "engine_options": "diffsurf_cli.presets",
    "read_target": "diffsurf_cli.io",
    "read_contactors": "diffsurf_cli.io",
    "project_dataframe": "diffsurf_cli.cluster",
}
__all__ = sorted(_PUBLIC)


def __getattr__(name):
    if name in _PUBLIC:
        import importlib

        value = getattr(importlib.import_module(_PUBLIC[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'diffsurf_cli' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))
