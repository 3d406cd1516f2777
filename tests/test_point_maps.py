"""The point rule's maps on mirror pairs equal the rule's own matrices, in fewer operations (issue 15).

:mod:`flexlink.mechanics.points` writes the running integral C = ``local + start·panel_sums`` and the nodal
shapes φ, φ' of a reduced FE link on the sums and differences of each panel's mirror pairs of Gauss points.
The references:

* the :class:`~flexlink.mechanics.shapes.base.PointRule`'s own dense matrices, C, Cᵀ, φ, φ' and their
  transposes, at random vectors (1e-14 of the result's scale);
* the integral itself, analytically: C applied to 6x⁵ at the points is x⁶ there (the six Gauss points of a
  panel interpolate a quintic exactly), on panels of unequal lengths;
* the operation counts of the same maps written with the dense panel blocks (``mirrored`` off).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from flexlink.mechanics.points import PointIntegration, PointShapes
from flexlink.mechanics.shapes.base import point_rule
from flexlink.mechanics.shapes.fe import HermiteFEBasis
from flexlink.mechanics.shapes.reduction import ModalBeamBasis


class _UnevenFE(HermiteFEBasis):
    """Hermite elements whose point rule cuts the link into panels of unequal lengths."""

    def panel_edges(self) -> np.ndarray:
        return np.array([0.0, 0.1, 0.35, 0.4, 0.8, 1.0]) * self.length


def _dense_C(rule) -> np.ndarray:
    return rule.local + rule.start @ rule.panel_sums


def _integration(rule, mirrored: bool | None = None) -> ca.Function:
    integral = PointIntegration(rule)
    if mirrored is not None:
        integral.mirrored = mirrored
    f = ca.MX.sym("f", len(rule.x))
    return ca.Function("C", [f], [integral(f), integral.transpose(f)]).expand()


RULES = {
    "16 equal elements": lambda: point_rule(HermiteFEBasis(count=16, length=1.0)),
    "unequal panels": lambda: point_rule(_UnevenFE(count=3, length=1.3)),
    "four points a panel": lambda: point_rule(HermiteFEBasis(count=5, length=0.8), order=4),
}


@pytest.mark.parametrize("name", RULES)
def test_the_mirrored_integral_is_the_rules_matrix(name):
    rule = RULES[name]()
    C = _dense_C(rule)
    rng = np.random.default_rng(7)
    f = rng.normal(size=len(rule.x))
    forward, backward = (np.asarray(v).ravel() for v in _integration(rule)(f))
    assert PointIntegration(rule).mirrored
    assert np.abs(forward - C @ f).max() <= 1e-14 * np.abs(C @ f).max()
    assert np.abs(backward - C.T @ f).max() <= 1e-14 * np.abs(C.T @ f).max()


def test_the_mirrored_integral_of_a_quintic_is_exact():
    """∫₀ˣ 6ξ⁵ dξ = x⁶: a panel's six points interpolate the integrand exactly, the running sum adds the panels."""
    rule = point_rule(_UnevenFE(count=3, length=1.3))
    x = rule.x
    forward, _ = (np.asarray(v).ravel() for v in _integration(rule)(6.0 * x**5))
    assert np.abs(forward - x**6).max() <= 1e-14 * (x**6).max()


def test_an_odd_rule_keeps_the_dense_blocks():
    rule = point_rule(HermiteFEBasis(count=4, length=1.0), order=5)
    assert not PointIntegration(rule).mirrored
    f = np.random.default_rng(3).normal(size=len(rule.x))
    forward, _ = (np.asarray(v).ravel() for v in _integration(rule)(f))
    assert np.abs(forward - _dense_C(rule) @ f).max() <= 1e-14 * np.abs(_dense_C(rule) @ f).max()


def test_the_mirrored_integral_takes_fewer_operations():
    """Two (n/2)² blocks a panel in place of one n² block: on 96 points, at most 0.7 of the dense form's count."""
    rule = point_rule(HermiteFEBasis(count=16, length=1.0))
    mirrored, dense = (_integration(rule, m).n_instructions() for m in (True, False))
    assert mirrored <= 0.7 * dense


def _shapes_function(rule, shapes: PointShapes) -> ca.Function:
    n, K = rule.phi.shape[1], len(rule.x)
    eta, values, slopes = ca.MX.sym("eta", n), ca.MX.sym("a", K), ca.MX.sym("b", K)
    at = shapes.at_points(eta)
    return ca.Function("S", [eta, values, slopes], [at[0], at[1], shapes.project(values, slopes)]).expand()


@pytest.mark.parametrize("count,modes", [(16, 32), (5, 4), (3, 6)])
def test_the_mirrored_shapes_are_the_rules_shapes(count, modes):
    """Values and slopes of η at the points, and φᵀa + φ'ᵀb, against the rule's nodal shapes and modes, to
    1e-14 of the sums' magnitudes (the modes in nodal values are large and cancel: 160 for values of 7).  A
    point's value is a sum and a difference of its pair's halves: its rounding is its panel's largest
    magnitude's, which near the clamped root is many times its own."""
    rule = ModalBeamBasis(HermiteFEBasis(count=count, length=1.1), modes).points
    shapes = PointShapes(rule)
    assert shapes.parts is not None
    factor = rule.factor
    rng = np.random.default_rng(count)
    eta, a, b = rng.normal(size=rule.phi.shape[1]), rng.normal(size=len(rule.x)), rng.normal(size=len(rule.x))
    values, slopes, projected = (np.asarray(v).ravel() for v in _shapes_function(rule, shapes)(eta, a, b))
    nodal, size = factor.modal @ eta, np.abs(factor.modal) @ np.abs(eta)
    back = factor.phi.T @ a + factor.slope.T @ b
    back_size = np.abs(factor.modal.T) @ (np.abs(factor.phi.T) @ np.abs(a) + np.abs(factor.slope.T) @ np.abs(b))
    panels = rule.panel_sums.shape[0]

    def of_panel(scale: np.ndarray) -> np.ndarray:
        return np.repeat(scale.reshape(panels, -1).max(axis=1), len(rule.x) // panels)

    for got, want, scale in ((values, factor.phi @ nodal, of_panel(np.abs(factor.phi) @ size)),
                             (slopes, factor.slope @ nodal, of_panel(np.abs(factor.slope) @ size)),
                             (projected, factor.modal.T @ back, back_size)):
        assert np.all(np.abs(got - want) <= 1e-14 * scale)
    # and the dense modal shapes the rule also holds, within the same magnitudes
    assert np.all(np.abs(values - rule.phi @ eta) <= 1e-14 * of_panel(np.abs(factor.phi) @ size))


def test_the_mirrored_shapes_take_fewer_operations():
    """The 32-mode link's points through even and odd coefficients against the nodal shapes' sparse rows (the
    modal maps are calls in both): at most 0.75 of the operations."""
    rule = ModalBeamBasis(HermiteFEBasis(count=16, length=1.0), 32).points
    shapes = PointShapes(rule)
    mirrored = _shapes_function(rule, shapes).n_instructions()
    shapes.parts = None
    assert mirrored <= 0.75 * _shapes_function(rule, shapes).n_instructions()
