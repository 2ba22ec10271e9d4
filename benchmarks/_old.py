"""An earlier version of diffsurf, built in a git worktree, to measure against in the same run.

`checkout(rev)` makes (once) a worktree of commit `rev` under benchmarks/out/old-REV, builds
its compiled parts in place, and returns its path: run it in a subprocess with that path first
on PYTHONPATH (`environ`: it shadows the installed package), or `load` its package in this
process.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the last commit before the one-engine rework (the ctypes C kernel and fastcsv)
BEFORE_ONE_ENGINE = "201ecf9"


def checkout(rev: str = BEFORE_ONE_ENGINE) -> Path:
    path = ROOT / "benchmarks" / "out" / f"old-{rev}"
    if not (path / "diffsurf_cli").exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-f", str(path),
                        rev], check=True, capture_output=True)
    if not list((path / "diffsurf_cli").glob("_ckernel*.so")):
        subprocess.run([sys.executable, "setup.py", "build_ext", "--inplace"], cwd=path,
                       check=True, capture_output=True)
    return path


def load(path: Path):
    """The old tree's ``diffsurf_cli`` package, imported from `path` in place of the installed
    one (its submodules follow; an editable install's import hook must be out of
    ``sys.meta_path`` first, or it maps them back to this tree)."""
    import importlib.util

    init = path / "diffsurf_cli" / "__init__.py"
    spec = importlib.util.spec_from_file_location(
        "diffsurf_cli", init, submodule_search_locations=[str(init.parent)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["diffsurf_cli"] = module
    spec.loader.exec_module(module)
    return module


def environ(path: Path) -> dict:
    """The environment of a subprocess that imports the old version."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(path), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env
