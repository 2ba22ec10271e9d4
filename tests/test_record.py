"""One output record shared by the passes (issue 31): `projection.allocate` makes the arrays
of `RECORD` (and `PAIRING_RECORD` or `PASS_RECORD`), and each compiled pass points its C
record at them by name, checking each (`mls._projection.record_of`): a missing, mistyped or
mis-sized array is one line naming it, never a write out of bounds."""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import (
    PAIRING_RECORD,
    PASS_RECORD,
    RECORD,
    Projection,
    allocate,
    recorded,
)
from diffsurf_cli.testing.shapes import Sphere


@pytest.fixture(scope="module")
def sphere():
    nodes, faces = Sphere().mesh(3)
    points = Sphere().sample_near(50, 0.05, rng=1)
    return nodes, faces, points


def test_allocate_holds_every_declared_array_with_its_fill():
    out = allocate(4, PASS_RECORD)
    assert set(out) == set(RECORD) | set(PASS_RECORD)
    for name, (dtype, shape, fill) in {**RECORD, **PASS_RECORD}.items():
        assert out[name].dtype == dtype and out[name].shape == (4, *shape)
        assert np.array_equal(out[name], np.full((4, *shape), fill, dtype), equal_nan=True)
    # what a pass records is exactly the Projection's fields it fills
    fields = set(Projection.__dataclass_fields__)
    assert set(recorded(allocate(1, PAIRING_RECORD, PASS_RECORD))) <= fields


def _engine_calls(nodes, faces, points):
    diffuse, patched = DiffuseSurface(nodes, faces), PatchedSurface(nodes, [faces])
    rows = np.arange(len(points), dtype=np.int64)
    index = np.empty((len(points), 0), np.int64)

    def diffuse_call(out):
        diffuse.engine.project(diffuse._options(), points, rows, out, index, 64)

    def patched_call(out):
        patched.engine.project(points, rows, out, 64)

    return [(diffuse_call, PAIRING_RECORD), (patched_call, PASS_RECORD)]


@pytest.mark.parametrize("which", [0, 1])
def test_the_passes_check_the_record_by_name(sphere, which):
    nodes, faces, points = sphere
    call, extra = _engine_calls(nodes, faces, points)[which]
    m = len(points)
    out = allocate(m, extra)
    call(out)  # the record as allocated: answered
    assert np.isfinite(out["gap"]).all()
    for name in ("gap", "curvature", next(iter(extra))):
        broken = dict(out)
        del broken[name]
        with pytest.raises(ValueError, match=f"lack '{name}'"):
            call(broken)
        short = dict(out)
        short[name] = out[name][:-1]
        with pytest.raises(ValueError, match=f"{name}.*expected {m} rows"):
            call(short)
    wrong = dict(out)
    wrong["status"] = out["status"].astype(np.int64)  # a mistyped array: refused, not cast
    with pytest.raises(ValueError):
        call(wrong)
