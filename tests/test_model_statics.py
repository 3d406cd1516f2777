"""Statics and gravity stiffening of the single-link model (issue "Single flexible link", item 4).

References, independent of flexlink: the strength-of-materials deflection of a cantilever under its own
weight, v(x) = −q x²(6L² − 4Lx + x²)/(24EI) (tip −qL⁴/(8EI), root moment −qL²/2), q = ρAg; and, for the
hanging link, a Rayleigh–Ritz / finite-element solution of our own with the geometric stiffness of the
axial tension N(x) = ρg(L − x) + m_tip g.  Run with ``pytest -s`` for the figures.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg
from conftest import EXAMPLES, make_link_scene
from numpy.polynomial.legendre import leggauss

from flexlink.mechanics.analysis import natural_frequencies, operating_point, static_deflection
from flexlink.mechanics.model import build_model
from flexlink.mechanics.shapes import make_basis
from flexlink.scene.loader import load_scene

G = 9.81
KINEMATICS = ("linear", "first-order", "second-order")


def _steel_beam(kind: str, count: int, kinematics: str):
    """examples/steel_beam_gravity.toml (seed 001 §4.8, held horizontal, gravity −y) with another basis."""
    scene = load_scene(EXAMPLES / "steel_beam_gravity.toml")
    link = scene.links[0]
    link = dataclasses.replace(link, shapes=dataclasses.replace(link.shapes, kind=kind, count=count),
                               kinematics=kinematics)
    return dataclasses.replace(scene, links=(link,))


def _static(model):
    """Static equilibrium of the held beam (operating_point) and its outputs."""
    op = operating_point(model)
    y = np.asarray(model.outputs_function(op.q, op.v, np.zeros(model.n_q), op.u, op.p)).ravel()
    return op, y


def _sag(x, q, length, ei):
    return -q * x**2 * (6 * length**2 - 4 * length * x + x**2) / (24 * ei)


@pytest.mark.parametrize("kinematics", KINEMATICS)
@pytest.mark.parametrize("count", [1, 3, 5])
def test_steel_beam_sag_fe_is_nodally_exact(kinematics, count):
    """Cubic Hermite elements with the consistent load vector are nodally exact for a uniform load."""
    scene = _steel_beam("fe", count, kinematics)
    link = scene.links[0]
    q, length, ei = link.linear_density * G, link.length, link.EI
    model = build_model(scene)
    op, y = _static(model)
    tip = y[model.output_index("beam.tip.v")]
    np.testing.assert_allclose(tip, -q * length**4 / (8 * ei), rtol=1e-12)
    assert tip < 0.0                                          # along −y, the gravity side
    nodes = np.linspace(0.0, length, count + 1)
    basis = make_basis("fe", count, length, link.linear_density)
    np.testing.assert_allclose(basis.evaluate(nodes) @ op.q, _sag(nodes, q, length, ei), rtol=1e-12, atol=1e-20)
    # the same through static_deflection itself, from the undeformed state
    q0, v0 = model.start_state()
    qs = static_deflection(model, q0, v0, op.u, op.p, list(range(model.n_q)))
    np.testing.assert_allclose(qs, op.q, rtol=1e-12, atol=1e-18)


def test_steel_beam_example_as_given():
    """The example file itself (5 elements, second order): 1.3118e-4 m downwards (seed §4.10: 0.13113e-3)."""
    scene = load_scene(EXAMPLES / "steel_beam_gravity.toml")
    link = scene.links[0]
    model = build_model(scene)
    _, y = _static(model)
    ref = -link.linear_density * G * link.length**4 / (8 * link.EI)
    np.testing.assert_allclose(y[model.output_index("beam.tip.v")], ref, rtol=1e-12)
    assert abs(ref + 1.3118e-4) < 5e-9


def test_polynomial_basis_holds_the_exact_quartic():
    """x², x³, x⁴ span the exact sag: tip and root moment EI v''(0) = −qL²/2 exact."""
    scene = _steel_beam("polynomial", 3, "second-order")
    link = scene.links[0]
    q = link.linear_density * G
    model = build_model(scene)
    _, y = _static(model)
    np.testing.assert_allclose(y[model.output_index("beam.tip.v")], -q * link.length**4 / (8 * link.EI), rtol=1e-12)
    np.testing.assert_allclose(y[model.output_index("beam.root.moment")], -q * link.length**2 / 2, rtol=1e-12)


def test_steel_beam_sag_eigenfunctions_converge():
    ref = -9.36 * G / (8 * 87498.6)
    counts = [1, 3, 6, 12, 24]
    errs = []
    for count in counts:
        model = build_model(_steel_beam("clamped-free", count, "second-order"))
        _, y = _static(model)
        errs.append(abs(y[model.output_index("beam.tip.v")] / ref - 1.0))
    rate = np.polyfit(np.log(counts[2:]), np.log(errs[2:]), 1)[0]
    print("\nsteel beam tip sag, eigenfunctions: relative error for " +
          ", ".join(f"{c}: {e:.2e}" for c, e in zip(counts, errs, strict=True)) + f"; log-log rate {rate:.2f}")
    assert all(b < a for a, b in zip(errs, errs[1:], strict=False))
    assert errs[-1] < 1e-7


# ---------------------------------------------------------------------------------------------------------
# Hanging link: gravity stiffening (second-order kinematics only)
# ---------------------------------------------------------------------------------------------------------

# The steel strip of examples/flexible_pendulum.toml (seed 001 §6.3): slender, so gravity matters.
STRIP = {"length": 0.835, "linear_density": 7800.0 * 0.15e-4, "EI": 0.315}
TIP_MASS = 0.031


def own_hanging_frequencies(n_el: int, length: float, rho: float, ei: float, g: float, tip_mass: float,
                            pinned: bool = False) -> np.ndarray:
    """Our own Hermite FE of a link hanging from a clamp (or a frictionless pin of zero inertia,
    ``pinned``): K = ∫EIφ''φ''ᵀ + ∫N φ'φ'ᵀ with the tension N(x) = ρg(L − x) + m_tip g, M = ∫ρφφᵀ +
    m_tip φ(L)φ(L)ᵀ; ω (rad/s), ascending. For the pin, φ is the absolute displacement (w(0) = 0 only) and
    ½∫N w'² is the weight's potential to second order (each section rises by ½∫₀ˣ w'² dξ)."""
    h = length / n_el
    t, w = leggauss(5)
    s, w = 0.5 * (t + 1.0), 0.5 * w * h
    n0 = np.stack([1 - 3 * s**2 + 2 * s**3, h * (s - 2 * s**2 + s**3), 3 * s**2 - 2 * s**3, h * (s**3 - s**2)], 1)
    n1 = np.stack([6 * s**2 - 6 * s, h * (1 - 4 * s + 3 * s**2), 6 * s - 6 * s**2, h * (3 * s**2 - 2 * s)], 1) / h
    n2 = np.stack([12 * s - 6, h * (6 * s - 4), 6 - 12 * s, h * (6 * s - 2)], 1) / h**2
    n = 2 * n_el + 2
    K, M = np.zeros((n, n)), np.zeros((n, n))
    for e in range(n_el):
        x = (e + s) * h
        tension = rho * g * (length - x) + tip_mass * g
        sl = slice(2 * e, 2 * e + 4)
        K[sl, sl] += (n2.T * (ei * w)) @ n2 + (n1.T * (w * tension)) @ n1
        M[sl, sl] += (n0.T * (rho * w)) @ n0
    M[-2, -2] += tip_mass
    first = 1 if pinned else 2
    w2 = scipy.linalg.eigh(K[first:, first:], M[first:, first:], eigvals_only=True)
    return np.sqrt(np.abs(w2))


def _hanging_model(kind, count, kinematics, gravity=True):
    scene = make_link_scene(kind, count, kinematics, drive="position", angle=-math.pi / 2,
                            gravity=(0.0, -G if gravity else 0.0, 0.0), payload={"mass": TIP_MASS}, **STRIP)
    return build_model(scene)


def _omegas(model):
    return 2 * np.pi * np.array(natural_frequencies(model, 0.0).frequencies_hz)


def test_hanging_link_is_stiffened_by_gravity():
    strip = {"length": STRIP["length"], "rho": STRIP["linear_density"], "ei": STRIP["EI"], "tip_mass": TIP_MASS}
    ref_g = own_hanging_frequencies(48, g=G, **strip)
    ref_0 = own_hanging_frequencies(48, g=0.0, **strip)
    hanging = _omegas(_hanging_model("fe", 8, "second-order"))[:3]
    plain = _omegas(_hanging_model("fe", 8, "second-order", gravity=False))[:3]
    print("\nhanging strip (L = 0.835 m, EI = 0.315 N m², tip 0.031 kg), position-held, f (Hz):"
          f"\n  own FE 48 el., gravity:    {ref_g[:3] / (2 * np.pi)}"
          f"\n  model FE 8, second-order:  {hanging / (2 * np.pi)}"
          f"\n  own FE 48 el., no gravity: {ref_0[:3] / (2 * np.pi)}"
          f"\n  model FE 8, no gravity:    {plain / (2 * np.pi)}")
    assert hanging[0] > 1.2 * plain[0]                      # +24 % on the first mode for this strip
    np.testing.assert_allclose(hanging, ref_g[:3], rtol=3e-3)
    np.testing.assert_allclose(plain, ref_0[:3], rtol=3e-3)
    np.testing.assert_allclose(hanging[0], ref_g[0], rtol=2e-5)


@pytest.mark.parametrize("kind, count", [("fe", 4), ("fe", 8), ("clamped-free", 4)])
def test_hanging_geometric_stiffness_on_the_same_basis(kind, count):
    """Rayleigh–Ritz with our geometric stiffness on the model's own shape functions (evaluated by the basis,
    integrated by our quadrature): the second-order model's matrices must give the same frequencies."""
    length, rho, ei = STRIP["length"], STRIP["linear_density"], STRIP["EI"]
    basis = make_basis(kind, count, length, rho)
    t, w = leggauss(40)
    edges = np.linspace(0.0, length, 4 * count + 1)
    x = np.concatenate([0.5 * (a + b) + 0.5 * (b - a) * t for a, b in zip(edges, edges[1:], strict=False)])
    wx = np.concatenate([0.5 * (b - a) * w for a, b in zip(edges, edges[1:], strict=False)])
    p0, p1, p2 = (basis.evaluate(x, k) for k in range(3))
    tension = rho * G * (length - x) + TIP_MASS * G
    tip = basis.evaluate([length])[0]
    K = (p2.T * (ei * wx)) @ p2 + (p1.T * (wx * tension)) @ p1
    M = (p0.T * (rho * wx)) @ p0 + TIP_MASS * np.outer(tip, tip)
    ref = np.sqrt(scipy.linalg.eigh(K, M, eigvals_only=True))
    np.testing.assert_allclose(_omegas(_hanging_model(kind, count, "second-order")), ref, rtol=1e-9)


@pytest.mark.parametrize("kinematics", ["linear", "first-order"])
def test_hanging_without_foreshortening_has_no_gravity_stiffness(kinematics):
    """Without the foreshortening u = −½∫v'² the weight does no work on v when the link hangs along the
    gravity: linear and first-order kinematics give the gravity-free frequencies (DESIGN.md §2)."""
    np.testing.assert_allclose(_omegas(_hanging_model("fe", 6, kinematics)),
                               _omegas(_hanging_model("fe", 6, kinematics, gravity=False)), rtol=1e-12)


def test_flexible_pendulum_example_free_pivot():
    """examples/flexible_pendulum.toml (free pivot, hanging, second order, 8 elements) against our pinned FE:
    pendulum and first flexible frequency with gravity (header: 0.6106 Hz and 4.788 Hz), and the first
    flexible frequency of the pinned-free strip with tip mass without gravity (header: 4.446 Hz, the seed's
    0.224 s period)."""
    scene = load_scene(EXAMPLES / "flexible_pendulum.toml")
    link = scene.links[0]
    strip = {"length": link.length, "rho": link.linear_density, "ei": link.EI, "tip_mass": link.payload.mass}
    ref_g = own_hanging_frequencies(48, g=G, pinned=True, **strip)[:2]
    ref_0 = own_hanging_frequencies(48, g=0.0, pinned=True, **strip)[1:2]     # [0] is the rigid rotation
    ours_g = _omegas(build_model(scene))[:2]
    ours_0 = _omegas(build_model(dataclasses.replace(scene, gravity=(0.0, 0.0, 0.0))))[:1]
    print(f"\nflexible pendulum, free pivot: gravity f = {ours_g / (2 * np.pi)} Hz (own FE {ref_g / (2 * np.pi)}); "
          f"no gravity {ours_0 / (2 * np.pi)} Hz (own FE {ref_0 / (2 * np.pi)})")
    err = np.abs(ours_g / ref_g - 1.0)
    assert err[0] < 1e-6 and err[1] < 5e-5, err
    np.testing.assert_allclose(ours_0, ref_0, rtol=5e-5)                     # 8 elements: h⁴ error
    assert abs(ref_g[0] / (2 * np.pi) - 0.6106) < 1e-4 and abs(ref_g[1] / (2 * np.pi) - 4.788) < 1e-3
    assert abs(ref_0[0] / (2 * np.pi) - 4.446) < 1e-3
