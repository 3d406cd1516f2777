"""controllers/crossovers.py's root refinement where a sign change of the sampled loop is a pole, not a crossing."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.crossovers import _roots


def test_a_bracket_whose_refinement_lands_on_a_pole_is_passed_over():
    """f(x) = (x − 4)/(x − 2): a root at 4 and a pole at 2, sampled at 1, 3, 5 (sign changes in both brackets).

    Near the pole the evaluation fails as a loop's response does there, a singular solve (a plate link's
    delayed LQG in CI: brentq converged onto the pole); the root at 4 is still found, to brentq's precision.
    """
    def f(x: float) -> float:
        if abs(x - 2.0) < 1e-9:
            raise np.linalg.LinAlgError("Singular matrix")
        return (x - 4.0) / (x - 2.0)

    w = np.array([1.0, 3.0, 5.0])
    roots = _roots(f, w, np.array([f(x) for x in w]), lambda x: abs(f(x)) < 1e-9)
    assert roots == [pytest.approx(4.0, rel=1e-12)]
