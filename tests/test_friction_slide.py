"""examples/friction_slide.py in quick mode (issue 23): the plate pressed and slid on the
faceted cylinder with Coulomb friction (μ = 0.2), diffuse, node-to-facet and exact: every step
converges, quadratically where the active and stick sets stay; the diffuse run's forces follow
the exact cylinder's within 1% at every slide step, where the facets' do not."""
from __future__ import annotations

import io

import pytest

from samples import load_example

pytest.importorskip("skfem")


@pytest.fixture(scope="module")
def quick():
    mod = load_example("friction_slide")
    out = io.StringIO()
    res = mod.run(quick=True, out=out)
    res["text"] = out.getvalue()
    return res


@pytest.mark.slow
def test_every_step_converges_quadratically(quick):
    for name, hist in quick["results"].items():
        assert all(s.converged for s in hist), (name, quick["text"])
        ratios = [q for s in hist for q in s.ratios()]
        # quadratic: r_{k+1} <= C r_k² wherever the active and stick sets stay (a linear
        # rate would make the ratio grow without bound as r_k falls), in the slip steps too
        assert len(ratios) >= 8 and max(ratios) <= 10.0, (name, quick["text"])
    slipping = [s.slipping for s in quick["results"]["diffuse"][quick["n_press"]:]]
    assert min(slipping) > 0, slipping


def test_diffuse_forces_follow_the_exact_cylinder(quick):
    summary = quick["summary"]
    assert summary["diffuse"]["dFt"] < 1.0 and summary["diffuse"]["dFn"] < 1.0, quick["text"]
    # the facets' sawtooth: many times further off
    assert summary["facet"]["dFt"] > 10 * summary["diffuse"]["dFt"], quick["text"]
