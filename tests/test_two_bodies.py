"""examples/two_bodies.py in quick mode (issue 21): two elastic bodies, the full diffuse element
with a frozen pairing per step: every step converges, quadratically where the active set stays;
the contact tangent is the derivative of the residual (finite differences, Taylor order 2);
the contact forces balance (forces and moments) and press the block down."""
from __future__ import annotations

import io

import pytest

from samples import load_example

pytest.importorskip("skfem")


@pytest.fixture(scope="module")
def quick():
    mod = load_example("two_bodies")
    out = io.StringIO()
    res = mod.run(quick=True, out=out)
    res["text"] = out.getvalue()
    return res


def test_every_step_converges_quadratically(quick):
    steps = quick["steps"]
    assert len(steps) == 3 and all(s.converged for s in steps), quick["text"]
    assert all(s.active[-1] > 0 for s in steps)
    assert all(len(s.residuals) - 1 <= 8 for s in steps), quick["text"]
    # quadratic: r_{k+1} <= C r_k² wherever the active set did not change (linear convergence
    # would make the ratio grow without bound as r_k falls); measured on several iterations
    assert len(quick["ratios"]) >= 3 and max(quick["ratios"]) <= 10.0, quick["text"]


def test_tangent_is_the_residuals_derivative(quick):
    fd = quick["fd"]
    assert fd["elements"] > 0
    assert fd["relative error"] <= 1e-6, fd
    assert 1.8 <= fd["order"] <= 2.3, fd


def test_contact_forces_balance_and_press_the_block(quick):
    bal = quick["balance"]
    assert bal["force"] <= 1e-12 and bal["moment"] <= 1e-12, bal
    assert bal["on the block"][1] < 0, bal  # the tube pushes the block down
    assert abs(bal["on the block"][0]) <= 1e-6 * abs(bal["on the block"][1])  # symmetric


@pytest.fixture(scope="module")
def sliding():
    """The quick model pressed, then the tube slid 1.0 along x in 4 steps with μ = 0.2."""
    mod = load_example("two_bodies")
    out = io.StringIO()
    res = mod.run(quick=True, out=out, mu=0.2, slide=1.0, slide_steps=4)
    res["text"] = out.getvalue()
    return res


def test_a_frictional_slide_converges_balanced_on_coulombs_cone(sliding):
    """Friction between the two deformable bodies (issue 33, item 2): every step converges,
    the tangent is the residual's derivative at the last step's start (stick and slip
    contactors both), the forces on block and tube balance, the slipping contactors are on
    Coulomb's cone, and the tube drags the block along the slide."""
    steps, slip = sliding["steps"], sliding["slip"]
    assert len(steps) == 7 and all(s.converged for s in steps), sliding["text"]
    assert max(len(s.residuals) - 1 for s in steps) <= 8, sliding["text"]
    assert sliding["fd"]["relative error"] <= 1e-6, sliding["fd"]
    assert 1.8 <= sliding["fd"]["order"] <= 2.3, sliding["fd"]
    assert sliding["balance"]["force"] <= 1e-12, sliding["balance"]
    assert slip["slip"] > 0 and slip["error"] <= 1e-12, slip
    on_block = sliding["balance"]["on the block"]
    assert on_block[0] > 0.05 * abs(on_block[1]), on_block  # along the slide, +x
