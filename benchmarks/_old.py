"""An earlier version of diffsurf, built in a git worktree, to measure against in the same run.

`checkout(rev)` makes (once) a worktree of commit `rev` under benchmarks/out/old-REV, builds
its compiled parts in place, and returns its path: run it in a subprocess with that path first
on PYTHONPATH (it shadows the installed package).
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


def environ(path: Path) -> dict:
    """The environment of a subprocess that imports the old version."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(path), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env
