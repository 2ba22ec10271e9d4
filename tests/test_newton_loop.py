"""A Newton loop a user can copy and trust (issue 33, item 4), on examples/two_bodies.py's
scene (quick): one load step pressing the tube 0.4 onto the block from rest makes plain
Newton cycle (the active set alternates between 9 contactors and none, the residual never
falls), while the loop's safeguards, a line search on the residual's norm or the
Gauss-Newton tangent on the step's first iterations, converge in a few iterations to 1e-10,
quadratically once the exact tangent takes over; and a contactor in `c.lost` stops the step
instead of being taken for open."""
from __future__ import annotations

import io

import numpy as np
import pytest

from samples import load_example

pytest.importorskip("skfem")

TOL = 1e-10


@pytest.fixture(scope="module")
def example():
    return load_example("two_bodies")


def _one_step(example, press, safeguard, maxit=30):
    out = io.StringIO()
    res = example.run(quick=True, press=press, steps=1, maxit=maxit, tol=TOL, out=out,
                      safeguard=safeguard)
    return res["steps"][0], out.getvalue()


@pytest.mark.parametrize("press", [0.4, 0.6])
def test_plain_newton_cycles(example, press):
    step, text = _one_step(example, press, None)
    assert not step.converged and not step.lost, text
    assert len(step.residuals) == 31
    # period 2: the active set and the residual repeat, and the residual does not fall
    tail = step.active[-10:]
    assert tail[0::2] == [tail[0]] * 5 and tail[1::2] == [tail[1]] * 5, tail
    assert tail[0] != tail[1]
    r = np.array(step.residuals[-10:])
    assert np.allclose(r[0::2], r[0], rtol=1e-6) and r.min() > 1e-2, r


@pytest.mark.parametrize("press", [0.4, 0.6])
@pytest.mark.parametrize("safeguard", ["line-search", "gauss-newton"])
def test_safeguarded_newton_converges(example, press, safeguard):
    step, text = _one_step(example, press, safeguard)
    assert step.converged and step.residuals[-1] <= TOL, text
    assert len(step.residuals) - 1 <= 10, text
    assert step.active[-1] > 0 and step.unanswered[-1] == 0 and not step.lost
    if safeguard == "line-search":
        assert min(step.lengths) < 1.0  # the line search did cut a step
    # quadratic once the exact tangent takes full steps on a fixed active set
    ratios = step.ratios(1e3 * TOL)
    assert ratios and max(ratios) <= 10.0, (ratios, text)


def test_a_lost_contactor_stops_the_step(example, monkeypatch):
    """A contactor without an answer that the facets find penetrating (`c.lost`) has no
    element: its force is missing, so the step stops unconverged (the caller cuts it)."""
    import diffsurf_cli

    real = diffsurf_cli.contact

    def losing(*args, **kwargs):
        c = real(*args, **kwargs)
        if kwargs.get("pairing") is not None:  # the iterations', not the pairing's search
            c.lost = np.array([0], dtype=np.int64)
        return c

    monkeypatch.setattr(diffsurf_cli, "contact", losing)
    step, text = _one_step(example, 0.2, "line-search")
    assert step.lost == 1 and not step.converged, text
    assert len(step.residuals) == 1
    assert "lost: cut the step" in text
