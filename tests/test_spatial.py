"""Spatial links and chains (issue 5): torsion and out-of-plane bending of a clamped-free link against their
closed forms, bending–torsion coupling through an offset tip payload against a finite-element code of our own
(numpy: Hermite bending in v and w, linear torsion elements, rigid offset mass at the tip), a non-planar
two-link chain (axes z then y: energy conservation, stiffening by rotation), and the size of the generated
model (a planar scene does not pay for the spatial coordinates). Run with ``pytest -s`` for the figures.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from conftest import EXAMPLES, clamped_free_lambdas
from numpy.polynomial.legendre import leggauss

from flexlink.mechanics.analysis import natural_frequencies
from flexlink.mechanics.model import build_model
from flexlink.mechanics.reference import simulate_reference
from flexlink.scene.loader import load_scene, parse_scene

# An aluminium-like bar with distinct stiffnesses in the three fields (SI)
BAR = {"length": 1.0, "linear_density": 2.0, "EI": 500.0, "EI_out": 200.0, "GJ": 100.0, "polar_inertia": 1e-3}


def held(name, axis=(0.0, 0.0, 1.0)):
    return {"name": name, "axis": list(axis), "drive": "position",
            "trajectory": {"segments": [{"until": math.inf, "poly": [0.0]}]}}


def bar(name, kind, count, deformation=("v", "w", "alpha"), kinematics="second-order", **extra):
    link = {"name": name, **BAR, "deformation": list(deformation), "shapes": {"kind": kind, "count": count},
            "kinematics": kinematics}
    link.update(extra)
    return link


def cantilever(kind, count, **extra):
    return parse_scene({"name": "spatial", "joint": [held("hub")], "link": [bar("arm", kind, count, **extra)]})


def hz(model, rate=0.0):
    return np.array(natural_frequencies(model, rate).frequencies_hz)


def closed_form_hz(n: int = 3) -> dict[str, np.ndarray]:
    L, rho = BAR["length"], BAR["linear_density"]
    lam2 = clamped_free_lambdas(n) ** 2
    i = np.arange(1, n + 1)
    return {"v": lam2 * math.sqrt(BAR["EI"] / (rho * L**4)) / (2 * math.pi),
            "w": lam2 * math.sqrt(BAR["EI_out"] / (rho * L**4)) / (2 * math.pi),
            "alpha": (2 * i - 1) * math.pi / (2 * L) * math.sqrt(BAR["GJ"] / BAR["polar_inertia"]) / (2 * math.pi)}


# ---------------------------------------------------------------------------------------------------------
# Torsion and out-of-plane bending
# ---------------------------------------------------------------------------------------------------------


def test_torsion_and_out_of_plane_closed_forms():
    """deformation = ["v", "w", "alpha"], joint held: the spectrum is the union of the in-plane bending
    λ_i² sqrt(EI/ρL⁴), the out-of-plane bending λ_i² sqrt(EI_out/ρL⁴) and the torsion
    (2i−1)π/(2L) sqrt(GJ/ρI_p). Eigenfunction bases are exact (they are the modes); finite elements converge
    at h⁴ (Hermite bending) and h² (linear torsion)."""
    ref = closed_form_hz(3)
    union = np.sort(np.concatenate(list(ref.values())))
    below = union[union < ref["alpha"][1]]                       # everything below the 2nd torsion mode
    exact = hz(build_model(cantilever("clamped-free", 4)))
    print("\nclosed forms (Hz): v " + str(ref["v"]) + ", w " + str(ref["w"]) + ", alpha " + str(ref["alpha"])
          + f"\nmodel, 4 eigenfunctions per field: {exact[:len(below)]}")
    np.testing.assert_allclose(exact[:len(below)], below, rtol=1e-10)
    errs = []
    for n in (8, 16):
        f = hz(build_model(cantilever("fe", n)))
        tors = f[np.argmin(np.abs(f - ref["alpha"][0]))]
        bend = f[np.argmin(np.abs(f - ref["w"][1]))]
        errs.append((tors / ref["alpha"][0] - 1, bend / ref["w"][1] - 1))
    errs = np.array(errs)
    print(f"FE 8 → 16 elements: torsion error {errs[:, 0]}, 2nd out-of-plane bending error {errs[:, 1]}")
    assert np.all(errs > 0)                                     # Rayleigh–Ritz: from above
    np.testing.assert_allclose(errs[0, 0] / errs[1, 0], 4.0, rtol=0.02)    # h²
    np.testing.assert_allclose(errs[0, 1] / errs[1, 1], 16.0, rtol=0.05)   # h⁴


# ---------------------------------------------------------------------------------------------------------
# Bending–torsion coupling through an offset payload: our own FE
# ---------------------------------------------------------------------------------------------------------

PAYLOAD = {"mass": 0.5, "inertia": [1e-3, 2e-3, 3e-3]}


def own_coupled_fe(n_el: int, offset) -> np.ndarray:
    """Node DOFs (v, v', w, w', α), root clamped; Hermite cubics for v (EI) and w (EI_out), hat functions for α
    (GJ, polar mass ρI_p). Payload at the tip: centre at the tip plus ψ × e (e = offset in the tip frame,
    ψ = (α, −w', v')): velocity (−e_z ẇ' − e_y v̇', v̇ − e_z α̇, ẇ + e_y α̇), rotary energy
    ½(J_xx α̇² + J_yy ẇ'² + J_zz v̇'²). Returns frequencies in Hz."""
    L, rho, mu = BAR["length"], BAR["linear_density"], BAR["polar_inertia"]
    h = L / n_el
    t, w = leggauss(6)
    s, w = 0.5 * (t + 1.0), 0.5 * w * h
    n0 = np.stack([1 - 3 * s**2 + 2 * s**3, h * (s - 2 * s**2 + s**3), 3 * s**2 - 2 * s**3, h * (s**3 - s**2)], 1)
    n2 = np.stack([12 * s - 6, h * (6 * s - 4), 6 - 12 * s, h * (6 * s - 2)], 1) / h**2
    l0, l1 = np.stack([1 - s, s], 1), np.stack([-np.ones_like(s), np.ones_like(s)], 1) / h
    nd = 5 * (n_el + 1)
    K, M = np.zeros((nd, nd)), np.zeros((nd, nd))
    for e in range(n_el):
        a, b = 5 * e, 5 * e + 5
        for first, stiff in ((0, BAR["EI"]), (2, BAR["EI_out"])):
            idx = [a + first, a + first + 1, b + first, b + first + 1]
            K[np.ix_(idx, idx)] += (n2.T * (stiff * w)) @ n2
            M[np.ix_(idx, idx)] += (n0.T * (rho * w)) @ n0
        idx = [a + 4, b + 4]
        K[np.ix_(idx, idx)] += (l1.T * (BAR["GJ"] * w)) @ l1
        M[np.ix_(idx, idx)] += (l0.T * (mu * w)) @ l0
    tip = 5 * n_el
    v, vs, wd, ws, al = (np.eye(nd)[tip + k] for k in range(5))
    ey, ez = offset[1], offset[2]
    vel = [-ez * ws - ey * vs, v - ez * al, wd + ey * al]
    for row in vel:
        M += PAYLOAD["mass"] * np.outer(row, row)
    for j, row in zip(PAYLOAD["inertia"], (al, ws, vs), strict=True):
        M += j * np.outer(row, row)
    keep = slice(5, nd)                                   # root node clamped
    w2 = scipy.linalg.eigh(K[keep, keep], M[keep, keep], eigvals_only=True)
    return np.sqrt(w2) / (2 * math.pi)


@pytest.mark.parametrize("offset", [(0.0, 0.08, 0.0), (0.0, 0.0, 0.08)], ids=["offset_v", "offset_w"])
def test_offset_payload_couples_bending_and_torsion(offset):
    """A 0.5 kg payload 8 cm off the axis along v couples w-bending and twist (along w: v and twist). Same
    mesh (6 elements): the model's FE equals ours to rounding; eigenfunctions (6 per field) approach our
    converged 96-element FE (slowly: 1 % on f3, f4 with 6 modes); the coupling is real (the spectrum
    differs from the centred payload's)."""
    payload = {**PAYLOAD, "offset": list(offset)}
    same = hz(build_model(cantilever("fe", 6, payload=payload)))
    ours6 = own_coupled_fe(6, offset)
    fine = own_coupled_fe(96, offset)
    modal = hz(build_model(cantilever("clamped-free", 6, payload=payload)))[:4]
    centred = own_coupled_fe(96, (0.0, 0.0, 0.0))
    print(f"\noffset {offset}: own FE 96 el. {fine[:4]} Hz; model FE 6 {same[:4]} (own FE 6 {ours6[:4]}); "
          f"model 6 eigenfunctions {modal}; centred payload {centred[:4]}")
    np.testing.assert_allclose(same, ours6, rtol=1e-9)
    # the free-end eigenfunctions carry the payload's inertial moment and shear only through many modes
    np.testing.assert_allclose(modal[:2], fine[:2], rtol=1e-3)
    np.testing.assert_allclose(modal, fine[:4], rtol=1.5e-2)
    assert np.max(np.abs(fine[:4] / centred[:4] - 1)) > 0.05


def test_spatial_cantilever_example():
    """examples/spatial_cantilever.toml: the header's frequencies are those of our own FE (96 elements)."""
    scene = load_scene(EXAMPLES / "spatial_cantilever.toml")
    pay = scene.links[0].payload
    assert pay.mass == PAYLOAD["mass"] and tuple(pay.inertia) == tuple(PAYLOAD["inertia"])
    ref = own_coupled_fe(96, pay.offset)[:4]
    np.testing.assert_allclose(ref, [3.91385, 6.19197, 23.9291, 37.2139], rtol=2e-4)
    np.testing.assert_allclose(hz(build_model(scene))[:4], ref, rtol=5e-4)          # 6 elements


# ---------------------------------------------------------------------------------------------------------
# A non-planar chain: axes z then y
# ---------------------------------------------------------------------------------------------------------


def spatial_chain(kinematics: str, drive: str = "free"):
    """Joint 1 about the vertical z, joint 2 about y of link 1's tip frame: link 2 swings in a vertical plane
    while the chain turns about z; gravity −z; link 1 bends in v, w and twists, link 2 bends in v and w and
    carries an offset payload with three inertias."""
    if drive == "free":
        j1 = {"name": "yaw", "axis": [0.0, 0.0, 1.0], "drive": "free", "inertia": 0.05, "initial_rate": 2.0}
        j2 = {"name": "pitch", "axis": [0.0, 1.0, 0.0], "drive": "free", "inertia": 0.01, "initial_angle": 0.3,
              "initial_rate": -1.0}
    else:
        j1, j2 = held("yaw"), held("pitch", (0.0, 1.0, 0.0))
    payload = {"mass": 0.2, "inertia": [1e-4, 2e-4, 3e-4], "offset": [0.0, 0.05, 0.02]}
    return parse_scene({"name": "yaw_pitch", "gravity": [0.0, 0.0, -9.81], "joint": [j1, j2],
                        "link": [bar("upper", "clamped-free", 2, kinematics=kinematics),
                                 bar("fore", "clamped-free", 2, ("v", "w"), kinematics=kinematics, payload=payload)]})


def test_spatial_chain_conserves_energy():
    """First-order kinematics (Lagrangian, nothing truncated), torques zero, gravity: T + V is invariant
    (CVODES rtol 1e-10) while the chain yaws, the forearm pitches and every field vibrates."""
    model = build_model(spatial_chain("first-order"))
    q0, v0 = model.start_state()
    q0[model.coordinates.index("upper.eta[1]")] = 0.01
    res = simulate_reference(model, np.linspace(0.0, 0.6, 61), q0=q0, v0=v0, rtol=1e-10, atol=1e-12)
    energy = res.output(model, "energy.kinetic") + res.output(model, "energy.potential")
    drift = np.max(np.abs(energy - energy[0])) / np.max(res.output(model, "energy.kinetic"))
    print(f"\nyaw–pitch chain, first order, gravity: yaw {np.ptp(res.output(model, 'yaw.theta')):.3f} rad, pitch "
          f"{np.ptp(res.output(model, 'pitch.theta')):.3f} rad; max|E − E0|/max T = {drift:.1e}")
    assert np.ptp(res.output(model, "yaw.theta")) > 0.5 and np.ptp(res.output(model, "pitch.theta")) > 0.2
    assert np.ptp(res.output(model, "fore.tip.w")) > 1e-4 and np.ptp(res.output(model, "upper.tip.twist")) > 0
    assert drift < 1e-8


def test_spatial_chain_stiffened_by_rotation():
    """Both joints held, the chain yawing steadily at W: with second-order kinematics the flexible frequencies
    rise with W (centrifugal stiffening), and always more than with first-order kinematics, which lacks the
    geometric stiffness (its in-plane modes soften, DESIGN.md §2)."""
    out = {}
    for kinematics in ("first-order", "second-order"):
        model = build_model(spatial_chain(kinematics, drive="position"))
        out[kinematics] = [hz(model, w)[:4] for w in (0.0, 3.0)]
    print("\nyaw–pitch chain held, f1..f4 (Hz) at W = 0 and 3 rad/s:"
          + "".join(f"\n  {k}: {a} → {b}" for k, (a, b) in out.items()))
    rest, spin = out["second-order"]
    assert np.all(spin > rest)
    assert np.all(spin / rest > out["first-order"][1] / out["first-order"][0])
    assert np.any(out["first-order"][1] < out["first-order"][0])


# ---------------------------------------------------------------------------------------------------------
# Size of the generated model
# ---------------------------------------------------------------------------------------------------------


def _size(scene):
    model = build_model(scene)
    return model.n_q, model.residual.expand().n_instructions(), model.outputs_function.expand().n_instructions()


@pytest.mark.parametrize("kinematics, ratio", [("first-order", 0.6), ("second-order", 0.85)])
def test_planar_scene_does_not_pay_for_spatial_coordinates(kinematics, ratio):
    """The same arm (4 elements) declared planar (["v"]) and spatial (["v", "w", "alpha"]): the planar model
    has exactly the 8 coordinates of v (the held joint is prescribed) and a smaller residual; a planar arm
    turning about another axis (y) costs the same as about z.  With second-order kinematics both carry the
    kinetic energy of the foreshortening at the link's Gauss points (u from v' alone, or from v' and w'),
    which planar and spatial share, so the planar saving is smaller there (0.78 of the spatial count)."""
    planar = _size(cantilever("fe", 4, deformation=["v"], kinematics=kinematics))
    spatial = _size(cantilever("fe", 4, kinematics=kinematics))
    tilted = _size(parse_scene({"name": "tilted", "joint": [held("hub", (0.0, 1.0, 0.0))],
                                "link": [bar("arm", "fe", 4, ["v"], kinematics=kinematics)]}))
    print(f"\nmodel size (coordinates, residual instructions, output instructions): planar {planar}, "
          f"planar about y {tilted}, spatial {spatial}")
    assert planar[0] == 8 and spatial[0] == 8 + 8 + 4           # joint held: a prescribed coordinate
    assert planar[1] < ratio * spatial[1] and planar[2] < spatial[2]
    assert tilted[0] == planar[0] and tilted[1] <= 1.1 * planar[1]
