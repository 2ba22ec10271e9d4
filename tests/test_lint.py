"""The tree is ruff-clean under the rules of pyproject.toml ([tool.ruff]): style, unused and
undefined names, import order, likely bugs; and its compiled engine (.pyx, .pxd) is
cython-lint-clean ([tool.cython-lint]). Both are in the `test` extra."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_ruff_is_clean():
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", str(ROOT)],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.slow
def test_cython_lint_is_clean():
    sources = sorted(str(p) for ext in ("*.pyx", "*.pxd")
                     for p in (ROOT / "diffsurf_cli").rglob(ext))
    assert sources
    result = subprocess.run([sys.executable, "-c", "from cython_lint.cython_lint import main; "
                             "raise SystemExit(main())", *sources],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
