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
    "eight points a panel": lambda: point_rule(HermiteFEBasis(count=4, length=1.0), order=8),
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


def _hermite_at_gauss_points(count: int, length: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """φ and φ' of clamped Hermite elements at each element's own Gauss points, from the textbook cubics of the
    local coordinate s = (1 + t)/2 (not through the rule's global abscissae)."""
    h = length / count
    t, _ = np.polynomial.legendre.leggauss(order)
    s = 0.5 * (1.0 + t)
    N = np.stack([1 - 3 * s**2 + 2 * s**3, h * (s - 2 * s**2 + s**3), 3 * s**2 - 2 * s**3, h * (s**3 - s**2)], 1)
    D = np.stack([6 * s**2 - 6 * s, h * (1 - 4 * s + 3 * s**2), 6 * s - 6 * s**2, h * (3 * s**2 - 2 * s)], 1) / h
    phi, slope = np.zeros((count * order, 2 * count)), np.zeros((count * order, 2 * count))
    for e in range(count):
        rows = slice(e * order, (e + 1) * order)
        phi[rows, 2 * e:2 * e + 2], slope[rows, 2 * e:2 * e + 2] = N[:, 2:], D[:, 2:]
        if e >= 1:                                  # the clamped root's node has no coordinates
            phi[rows, 2 * e - 2:2 * e], slope[rows, 2 * e - 2:2 * e] = N[:, :2], D[:, :2]
    return phi, slope


SHAPE_RULES = {            # (elements, length, modes, points a panel)
    "32 modes of 16 elements": (16, 1.1, 32, 6),
    "4 modes of 5 elements": (5, 1.1, 4, 6),
    "6 modes of 3 elements": (3, 1.1, 6, 6),
    # short elements: slopes 1/h and rotations' values h apart, the rule's φ' with 1e-11 of rounding
    "a 1 cm link of 16 elements": (16, 0.01, 16, 6),
    "200 elements of 5 mm": (200, 1.0, 8, 6),
    "four points a panel": (6, 0.9, 5, 4),
}


@pytest.mark.parametrize("name", SHAPE_RULES)
def test_the_mirrored_shapes_are_the_hermite_cubics(name):
    """Values and slopes of η at the points, and φᵀa + φ'ᵀb, against the Hermite cubics at each element's own
    Gauss points and against the rule's nodal shapes, to 3e-13 of each panel's magnitudes (the modes in nodal
    values are large and cancel: 160 for values of 7).  A point's value is a sum and a difference of its pair's
    halves: its rounding is its panel's largest magnitude's.  The bound is the rule's own: its φ entries carry
    the rounding of the global abscissae (s = x/h − k, eps·x/h: 2e-14 at the 144th of 200 elements), which
    the rows of φ cancel (N1 + N3 = 1) and the monomial coefficients fitted to them keep, 1.1e-13 of the
    panel's values there; 2e-15 to 2e-14 on the other rules."""
    count, length, modes, order = SHAPE_RULES[name]
    rule = point_rule(ModalBeamBasis(HermiteFEBasis(count=count, length=length), modes), order=order)
    shapes = PointShapes(rule)
    assert shapes.parts is not None
    assert shapes.parts.T_e.shape[0] == shapes.parts.T_o.shape[0] == 2 * count      # a cubic's two and two
    factor = rule.factor
    rng = np.random.default_rng(len(rule.x))
    eta, a, b = rng.normal(size=rule.phi.shape[1]), rng.normal(size=len(rule.x)), rng.normal(size=len(rule.x))
    values, slopes, projected = (np.asarray(v).ravel() for v in _shapes_function(rule, shapes)(eta, a, b))
    nodal, size = factor.modal @ eta, np.abs(factor.modal) @ np.abs(eta)

    def of_panel(scale: np.ndarray) -> np.ndarray:
        return np.repeat(scale.reshape(count, -1).max(axis=1), order)

    phi, slope = _hermite_at_gauss_points(count, length, order)
    back_size = np.abs(factor.modal.T) @ (np.abs(phi.T) @ np.abs(a) + np.abs(slope.T) @ np.abs(b))
    for reference, reference_slope in ((phi, slope), (factor.phi, factor.slope)):
        back = factor.modal.T @ (reference.T @ a + reference_slope.T @ b)
        for got, want, scale in ((values, reference @ nodal, of_panel(np.abs(phi) @ size)),
                                 (slopes, reference_slope @ nodal, of_panel(np.abs(slope) @ size)),
                                 (projected, back, back_size)):
            assert np.all(np.abs(got - want) <= 3e-13 * scale)


def test_the_mirrored_shapes_take_fewer_operations():
    """The 32-mode link's points through even and odd coefficients against the nodal shapes' sparse rows (the
    modal maps are calls in both): at most 0.7 of the operations."""
    rule = ModalBeamBasis(HermiteFEBasis(count=16, length=1.0), 32).points
    shapes = PointShapes(rule)
    mirrored = _shapes_function(rule, shapes).n_instructions()
    shapes.parts = None
    assert mirrored <= 0.7 * _shapes_function(rule, shapes).n_instructions()
