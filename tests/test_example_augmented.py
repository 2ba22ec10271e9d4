"""examples/augmented_lagrangian.py (issue 33, item 3) in-process: Uzawa's loop with the
element's API drives the penetration to round-off in a few augmentations on a rigid and a
deformable target, each augmentation dividing it by about 1 + ε / k, every Newton solve
converged, and the multipliers carrying the contact force."""
from __future__ import annotations

import io

import numpy as np
import pytest

from samples import load_example


@pytest.fixture(scope="module")
def result():
    mod = load_example("augmented_lagrangian")
    out = io.StringIO()
    res = mod.run(out=out)
    res["text"] = out.getvalue()
    res["module"] = mod
    return res


@pytest.mark.parametrize("scene", ["rigid", "deformable"])
def test_penetration_to_round_off_in_a_few_augmentations(result, scene):
    mod, r = result["module"], result[scene]
    assert r["converged"], result["text"]
    pen = np.array(r["penetration"])
    assert len(pen) <= 10 and pen[-1] <= mod.DONE, result["text"]
    # the penalty alone leaves a penetration of about force / ε; each augmentation divides it
    # by about 1 + ε / k (linear convergence of Uzawa's loop)
    assert pen[0] > 1e-3, result["text"]
    rates = pen[1:] / pen[:-1]
    assert np.all(rates < 1.5 * mod.SPRING / (mod.SPRING + mod.EPS)), rates
    assert (r["multipliers"] < 0).sum() >= 3


def test_plain_penalty_is_the_first_solve(result):
    # augmentation 0 has no multipliers: the penalty's own penetration, 0.5 / 31 for the rigid
    # scene's 0.5 mm pull on springs of stiffness 1 with ε = 30 (a curved target: roughly)
    assert result["rigid"]["penetration"][0] == pytest.approx(0.5 / 31, rel=0.05)
