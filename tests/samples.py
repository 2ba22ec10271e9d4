"""What the tests share: the bundled sample meshes, and running the command line in-process.

Test modules import these names (``from samples import CYLINDER, run``): pytest puts this
folder on the path, as it does for the slow references (`reference.py`, ...).
"""
from __future__ import annotations

import os
import pty
import subprocess
import tempfile
from pathlib import Path

from click.testing import CliRunner

SAMPLES = Path(__file__).resolve().parent.parent / "sample_meshes"
#: a coarse half cylinder of quads (85 nodes, 64 facets), radius 10 around (32.5, 30)
CYLINDER = str(SAMPLES / "cylinder.msh")
CYLINDER_STL = str(SAMPLES / "cylinder_tri.stl")
#: the plate and the cylinder in one Gmsh file, with physical groups 'plate' and 'cylinder'
BOTH = str(SAMPLES / "plate_and_cylinder.msh")
#: the plate's 265 nodes, as CSV (with an id column) and as a mesh
PLATE_CSV = str(SAMPLES / "plate.csv")
PLATE_VTU = str(SAMPLES / "plate.vtu")
N_PLATE = 265
N_CYLINDER_POINTS = 85


def load_example(name: str):
    """examples/`name`.py as a module (registered in sys.modules: its dataclasses look their
    module up there)."""
    import importlib.util
    import sys

    path = Path(__file__).resolve().parent.parent / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def run(*args, input=None, catch_exceptions=True):
    """`diffsurf ARGS...` in-process (click's CliRunner); stdout and stderr kept apart."""
    from diffsurf_cli.cli import main

    return CliRunner().invoke(main, [str(a) for a in args], input=input,
                              catch_exceptions=catch_exceptions)


def run_on_terminal(cmd: list, timeout: float) -> tuple:
    """Run `cmd` with stderr a pseudo-terminal (progress bars and status lines draw there):
    (returncode, stdout bytes, stderr bytes). stdout goes to a file, not a pipe, so that it
    cannot fill and block the child while the terminal is drained."""
    master, slave = pty.openpty()
    sink = tempfile.TemporaryFile()
    p = subprocess.Popen(cmd, stdout=sink, stderr=slave)
    os.close(slave)
    err = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        err += chunk
    p.wait(timeout=timeout)
    os.close(master)
    sink.seek(0)
    return p.returncode, sink.read(), err
