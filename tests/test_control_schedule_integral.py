"""Integral action in the scheduled LQG (controllers.integral, issue 16) on examples/two_link_payload.toml:
shoulder 0 → 60°, elbow −20° → 90° in 1.5 s, the LQG scheduled at three poses along the path.

* at each design point the augmented gains (K_x, K_ξ) are python-control's ``dlqr`` on the plant linearised
  there from a scene *built* with the joints' ``initial_angle`` at that pose, sampled by python-control's
  ``sample_system`` and augmented here with the integrals of its joint-angle outputs, with Bryson's weights
  written here; between points the law's gains are the linear interpolation of those in σ;
* through the FMU, with a constant torque the model lacks (2 N m at the shoulder, −1 N m at the elbow)
  through the manoeuvre and a 6 s settle: the scheduled LQG ends with the steady joint error that
  python-control's DC gain of its closed loop at the target pose predicts; the scheduled LQG with integral
  action ends below 20 ρ^N of it (ρ the slowest pole of that loop with the integrators, N the settle's
  samples), settled;
* the frozen-pose margins along the path of the integral loops against python-control's, a stable loop whose
  phase margin python-control gives as −19.56° (a lead destabilises it) among them;
* the controller FMU of the scheduled integral law equals the Python law in closed loop with the plant FMU;
* the SSP package of the scheduled integral law run by libcosim equals the plant FMU with the Python law one
  sample late (``ScheduledPredictiveIntegralLQGLaw``);
* ``flexlink control --integral TI --schedule N``: the run and ``--design-only``, ``--json``, ``--export-fmu``,
  ``--export-ssp``.
"""

from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest
from conftest import EXAMPLES, BiasedLaw, assert_runs_equal, two_link_plant_at
from fmpy.ssp.ssd import read_ssd

from controllers.cosim import FmuLoop
from controllers.integral import ScheduledIntegralLQGLaw, design_scheduled_integral, sampled_integral_compensator
from controllers.manoeuvre import design
from controllers.multijoint import inverse_dynamics_reference, plan, run
from controllers.schedule import ScheduledLQGLaw, along_path, design_schedule, path_fraction
from controllers.ssp import CONTROLLER, PLANT, JacobiDelay, ScheduledPredictiveIntegralLQGLaw, write_ssp
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.importers import libcosim_available, run_libcosim_ssp

SCENE = EXAMPLES / "two_link_payload.toml"
TARGETS = [math.radians(60.0), math.radians(90.0)]
JOINTS = ("shoulder", "elbow")
SENSORS = ("shoulder.theta", "elbow.theta", "upper.root.moment", "fore.root.moment")
DT, DURATION, LIMIT, POINTS, TI = 1e-3, 1.5, 60.0, 3, 0.5
BIAS = np.array([2.0, -1.0])                     # N m the model lacks, added between the law and the plant


@pytest.fixture(scope="module")
def sched():
    d = design(build_model(load_scene(SCENE)), torque_limit=LIMIT, dt=DT)
    pl = plan(d.plant, TARGETS)
    s = design_schedule(d, pl, POINTS)
    return d, pl, s, design_scheduled_integral(s, TI)


def built_at(pose: dict):
    """The example's scene with its joints' initial_angle at ``pose``, built and linearised afresh."""
    return two_link_plant_at(tuple(pose[j] for j in JOINTS))


def sampled(p):
    """python-control's ZOH-sampled plant from the two torques to the Kalman sensors."""
    cols = [p.inputs.index(f"{j}.tau") for j in JOINTS]
    C = p.sys.C[[p.output_row(s) for s in SENSORS]]
    return ct.sample_system(ct.ss(p.sys.A, p.sys.B[:, cols], C, 0), DT, method="zoh")


def augmented_dlqr(p, limits: dict) -> np.ndarray:
    """python-control's dlqr on the sampled plant with the integrals of the joint angles appended."""
    Pd = sampled(p)
    Ad, Bd = np.asarray(Pd.A), np.asarray(Pd.B)
    n = Ad.shape[0]
    Ce = p.sys.C[[p.output_row(f"{j}.theta") for j in JOINTS]]
    Aa = np.block([[Ad, np.zeros((n, 2))], [DT * Ce, np.eye(2)]])
    Ba = np.vstack([Bd, np.zeros((2, 2))])
    # Bryson's rule with the design's declared limits (0.5° per joint, 5 mm per tip, 6 N m per root) and
    # 1/(e_max T_i)² on each joint's error integral
    Cz = p.sys.C[[p.output_row(z) for z in limits]]
    Q = Cz.T @ np.diag([1 / v**2 for v in limits.values()]) @ Cz
    Qa = np.zeros((n + 2, n + 2))
    Qa[:n, :n] = 0.5 * (Q + Q.T)
    Qa[n:, n:] = np.eye(2) / (math.radians(0.5) * TI) ** 2
    K, _, _ = ct.dlqr(Aa, Ba, Qa, np.eye(2) / LIMIT**2)
    return np.asarray(K)


def test_augmented_gains_at_each_point_are_python_controls_dlqr(sched):
    d, pl, s, si = sched
    assert set(d.lqr.limits) >= {"shoulder.theta", "elbow.theta"}
    gains = []
    for pose, integ in zip(s.poses, si.designs, strict=True):
        K = augmented_dlqr(built_at(pose), d.lqr.limits)
        n = K.shape[1] - 2
        scale = np.max(np.abs(K))
        np.testing.assert_allclose(integ.Kx, K[:, :n], atol=1e-6 * scale)
        np.testing.assert_allclose(integ.Ki, K[:, n:], atol=1e-6 * scale)
        gains.append(K)
    # the law between the first two points: the gains interpolated linearly in the path parameter
    ref = inverse_dynamics_reference(d.plant, pl, DT, DURATION, 0.5)
    law = ScheduledIntegralLQGLaw(si, [LIMIT, LIMIT], ref)
    sigma = path_fraction(ref)
    k = int(np.argmin(np.abs(sigma - 0.2)))
    lam = sigma[k] / s.sigma[1]
    K = (1 - lam) * gains[0] + lam * gains[1]
    n = K.shape[1] - 2
    scale = np.max(np.abs(K))
    np.testing.assert_allclose(law.matrices(k)[2], K[:, :n], atol=1e-6 * scale)
    np.testing.assert_allclose(law.integral_gain(k), K[:, n:], atol=1e-6 * scale)


def Biased(law):
    return BiasedLaw(law, BIAS)


def test_constant_disturbance_through_the_fmu(sched, example_fmu):
    """The manoeuvre with ``BIAS`` throughout and a 6 s settle.  The scheduled LQG (the target design's
    matrices from the manoeuvre's end) ends with python-control's DC-gain error of its closed loop with the
    plant built at the target pose; with integral action the error falls below 20 ρ^N of that, and the run
    settles (joints within 0.1°, tips within 1 mm)."""
    d, pl, s, si = sched
    settle = 6.0
    p = built_at(s.poses[-1])
    M, C, K, Ad, Bd = s.matrices(1.0)
    n = Ad.shape[0]
    F, Acl = np.eye(n) - M @ C, Ad - Bd @ K
    lqg = ct.ss(Acl @ F, Acl @ M, -K @ F, -K @ M, DT)
    expected = np.degrees((np.asarray(ct.dcgain(ct.feedback(sampled(p), lqg, sign=1))) @ BIAS)[:2])
    T = ct.series(sampled(p), sampled_integral_compensator(si.matrices(1.0), si.designs[-1].rows, DT))
    rho = float(np.max(np.abs(ct.feedback(T, np.eye(2), sign=1).poles())))
    N = int(round(settle / DT))
    ref = inverse_dynamics_reference(d.plant, pl, DT, DURATION, settle)
    laws = {"lqg": ScheduledLQGLaw(s, [LIMIT, LIMIT], ref),
            "integral": ScheduledIntegralLQGLaw(si, [LIMIT, LIMIT], ref)}
    errors, metrics = {}, {}
    with FmuLoop(example_fmu("two_link_payload")) as fl:
        for name, law in laws.items():
            res = run(d, fl, pl, ref, Biased(law))
            errors[name] = np.degrees([res.series[f"{j}.theta"][-1] - t for j, t in zip(JOINTS, TARGETS, strict=True)])
            metrics[name] = res.metrics
    print(f"\nsteady errors (deg): scheduled LQG {errors['lqg']}, python-control {expected}; with integral action "
          f"{errors['integral']} (slowest pole {rho:.5f}, 20 rho^N = {20 * rho ** N:.2e}); settling "
          f"{metrics['integral']['settling_time_s']} s")
    assert errors["lqg"] == pytest.approx(expected, rel=2e-3)
    assert np.all(np.abs(errors["integral"]) < 20 * rho**N * np.abs(expected))
    assert metrics["integral"]["settling_time_s"] is not None


def broken(T, i: int):
    """python-control's loop broken at input i of T (positive feedback), the other channel closed:
    ``L = −feedback(T, E_o, sign=1)[i, i]``, negative-feedback convention of ``stability_margins``."""
    return -ct.feedback(T, np.diag([0.0 if k == i else 1.0 for k in range(2)]), sign=1)[i, i]


def python_control_crossovers(L, points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """python-control's crossovers of L (``stability_margins``, returnall, on ``control.frd`` of L):
    located on a 6000-point grid to Nyquist, then each found again on a grid of ``points`` points within
    ±0.1 % of it (python-control refines on the table's spline, whose error falls as the grid tightens).
    Returns (gains 1/|L| at the phase crossovers, their rad/s, signed phase margins at the gain crossovers,
    their rad/s)."""
    import warnings

    def margins(w):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gm, pm, _, wpc, wgc, _ = ct.stability_margins(ct.frd(L, w, smooth=True), returnall=True)
        return np.asarray(gm), np.asarray(pm), np.asarray(wpc), np.asarray(wgc)

    _, _, wpc0, wgc0 = margins(np.logspace(-3, np.log10(np.pi / DT), 6000)[:-1])
    gm, wpc, pm, wgc = [], [], [], []
    for w0 in wpc0:
        g, _, x, _ = margins(np.linspace(w0 * (1 - 1e-3), w0 * (1 + 1e-3), points))
        k = int(np.argmin(np.abs(x - w0)))
        gm.append(g[k])
        wpc.append(x[k])
    for w0 in wgc0:
        _, q, _, x = margins(np.linspace(w0 * (1 - 1e-3), w0 * (1 + 1e-3), points))
        k = int(np.argmin(np.abs(x - w0)))
        pm.append(q[k])
        wgc.append(x[k])
    return np.array(gm), np.array(wpc), np.array(pm), np.array(wgc)


def test_margins_along_the_path_against_python_control(sched):
    """At the target pose (σ = 1) and between the first two points (σ = 0.25), the integral loops' margins that
    along_path reports on its default grid equal python-control's on the loop built with the plant linearised
    afresh there, every crossover to 1e-6 dB and 1e-6°.

    At σ = 0.25 the elbow's phase crossover (495 Hz) is sharp: python-control's ``stability_margins`` on the
    4000-point table refines it on the table's spline and gives 1.7074 dB; its crossover found again on 400 and
    4000 points within ±0.1 % gives the loop's 1.720427 dB (the two grids agree to 1e-9 dB, the
    convergence shown), which along_path's crossovers, refined on the loop itself, equal."""
    d, pl, s, si = sched
    along = along_path(d, s, pl, [0.25, 1.0], integral=si)
    for i, sigma in enumerate((0.25, 1.0)):
        pose = {j: a + sigma * (b - a) for j, a, b in zip(pl.joints, pl.angle_start, pl.target, strict=True)}
        pt = along["scheduled"]["points"][i]
        T = ct.series(sampled(built_at(pose)), sampled_integral_compensator(si.matrices(sigma), si.designs[0].rows, DT))
        rho = float(np.max(np.abs(ct.feedback(T, np.eye(2), sign=1).poles())))
        assert pt["stable"] and pt["spectral_radius"] == pytest.approx(rho, rel=1e-6)
        for k, fig in enumerate(pt["actuators"]):
            coarse, fine = (python_control_crossovers(broken(T, k), n) for n in (400, 4000))
            gm_db, pm = 20 * np.log10(fine[0]), fine[2]
            np.testing.assert_allclose(20 * np.log10(coarse[0]), gm_db, atol=1e-8)      # converged
            np.testing.assert_allclose(coarse[2], pm, atol=1e-8)
            ours = np.array(fig["phase_crossovers"])
            np.testing.assert_allclose(ours[:, 1], gm_db, atol=1e-6)
            np.testing.assert_allclose(ours[:, 0], fine[1] / (2 * np.pi), rtol=1e-9)
            np.testing.assert_allclose(np.array(fig["gain_crossovers"])[:, 1], pm, atol=1e-6)
            assert fig["gain_margin_db"] == pytest.approx(np.min(gm_db[gm_db > 0]), abs=1e-6)
            assert fig["phase_margin_deg"] == pytest.approx(np.min(np.abs(pm)), abs=1e-6)
            print(f"\nsigma {sigma} {fig['input']}: gain margin {fig['gain_margin_db']:.7f} dB, python-control "
                  f"{np.min(gm_db[gm_db > 0]):.7f} dB; phase margin {fig['phase_margin_deg']:.6f} deg "
                  f"({fig['phase_margin_sense']})")
    assert along["scheduled"]["worst"]["stable"]


def test_a_lead_phase_margin_on_a_stable_loop(sched):
    """At σ = 0.25 the shoulder's loop (the elbow's closed) is stable with two poles of its own outside the unit
    circle (python-control: the elbow's loop alone does not hold the arm there), so its Nyquist curve must
    encircle −1 twice and crosses the unit circle on both sides of it.  python-control's
    ``stability_margins`` gives the crossover of smallest |pm| as −19.56° (at 243 Hz): a phase *lead* of
    19.56° destabilises, not a lag.  along_path reports 19.56°, sense ``lead``, the two poles, every crossover
    as python-control's signed figures; and the loop with L rotated by e^{±jφ} (its closed-loop matrix, numpy's
    eigenvalues) is stable for |φ| 1 % below that margin and not 1 % above it, in either direction."""
    d, pl, s, si = sched
    sigma = 0.25
    fig = along_path(d, s, pl, [sigma], integral=si)["scheduled"]["points"][0]["actuators"][0]
    pose = {j: a + sigma * (b - a) for j, a, b in zip(pl.joints, pl.angle_start, pl.target, strict=True)}
    T = ct.series(sampled(built_at(pose)), sampled_integral_compensator(si.matrices(sigma), si.designs[0].rows, DT))
    L = broken(T, 0)
    assert np.max(np.abs(ct.feedback(L, 1).poles())) < 1
    # python-control's poles of L: two outside the unit circle, and the shoulder's rigid-body double integrator
    # with its error integral, a triple pole at z = 1 that rounding scatters by 2e-7 (on the circle: not counted)
    p = np.abs(L.poles())
    assert np.sum(np.abs(p - 1) < 1e-6) == 3
    assert fig["open_loop_unstable_poles"] == int(np.sum(p > 1 + 1e-6)) == 2
    _, _, pm, wgc = python_control_crossovers(L, 4000)
    k = int(np.argmin(np.abs(pm)))
    assert pm[k] < 0 and fig["phase_margin_sense"] == "lead"
    assert fig["phase_margin_deg"] == pytest.approx(-pm[k], abs=1e-6)
    assert fig["gain_crossover_hz"] == pytest.approx(wgc[k] / (2 * np.pi), rel=1e-9)
    A, B, C, D = (np.asarray(M, dtype=float) for M in (L.A, L.B, L.C, L.D))

    def radius(phi_deg: float) -> float:
        g = np.exp(1j * np.radians(phi_deg))          # u = −g y: x⁺ = (A − B g (1 + g D)⁻¹ C) x
        return float(np.max(np.abs(np.linalg.eigvals(A - B @ (g / (1 + g * D)) @ C))))

    for sign in (1, -1):
        assert radius(sign * 0.99 * fig["phase_margin_deg"]) < 1 < radius(sign * 1.01 * fig["phase_margin_deg"])


def test_cli(capsys):
    """``flexlink control --integral TI --schedule N``: the run (--json: both laws' figures, the integral
    time, the margins along the path) and ``--design-only``."""
    from flexlink.cli import main

    base = ["control", str(SCENE), "--target", "60,90", "--duration", "1.5", "--torque-limit", "60",
            "--integral", "0.5", "--schedule", "3", "--json"]
    assert main(base) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["integral_time_s"] == 0.5 and doc["schedule"]["points"] == 3
    assert doc["scheduled"]["settling_time_s"] is not None
    for j, t in zip(JOINTS, (60.0, 90.0), strict=True):
        assert abs(doc["scheduled"]["joints"][j]["final_error_deg"]) < 0.1, t
    assert doc["robustness_along_path"]["scheduled"]["worst"]["stable"]
    assert len(doc["robustness_along_path"]["scheduled"]["points"]) == 4 * 3 - 3
    assert main([*base, "--design-only"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["robustness"]["lqg_integral"]["stable"] and doc["robustness_along_path"]["scheduled"]["worst"]["stable"]


def test_controller_fmu_equals_the_python_scheduled_integral_law(sched, example_fmu, tmp_path):
    """The controller FMU of the scheduled integral law (``ctrl_fmu.c``: ``SKD`` = K_x and ``SKI`` = K_ξ per
    design point, interpolated in C) passes fmpy's validation and ``flexlink check``, and with the plant FMU,
    stepped by fmpy, it equals the Python ``ScheduledIntegralLQGLaw`` to 1e-9 of every series' scale, with
    the constant disturbance of the test above (the integrators are exercised)."""
    from fmpy.validation import validate_fmu

    from controllers.export import FmuLaw, export_controller_fmu

    d, pl, s, si = sched
    settle = 1.5
    fmu = export_controller_fmu(d, tmp_path / "ctrl.fmu", schedule=s, duration=DURATION, integral=si)
    from flexlink.cli import main

    assert validate_fmu(str(fmu)) == []
    assert main(["check", str(fmu), "--report", str(tmp_path / "check")]) == 0
    ref = inverse_dynamics_reference(d.plant, pl, DT, DURATION, settle)
    law = ScheduledIntegralLQGLaw(si, [LIMIT, LIMIT], ref)
    ctrl = FmuLaw(fmu, law.W)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=["upper.tip.v", "fore.tip.v"]) as loop:
            a = loop.run(Biased(law), ref)
            b = loop.run(Biased(ctrl), ref)
    finally:
        ctrl.close()
    assert np.max(np.abs(law.xi)) > 1e-4
    worst = assert_runs_equal(a, b)
    print(f"\nlargest difference FMU - Python: {worst}")


@pytest.mark.skipif(not libcosim_available(), reason="libcosimpy is not installed")
def test_libcosim_runs_the_scheduled_integral_package_as_the_python_law(sched, example_fmu, tmp_path):
    """The SSP package of the scheduled integral law (its controller FMU ``DELAY 1`` with ``INTEGRAL 1`` and
    ``NSCHED 3``: the next sample's K_x and K_ξ for the torque it outputs) run by libcosim (its own SSP parser
    and Jacobi master) equals, to 1e-9 of every series' scale, the plant FMU stepped by fmpy with the Python
    law one sample late (``JacobiDelay(ScheduledPredictiveIntegralLQGLaw)``); the integrators act (ξ ≠ 0)."""
    d, pl, s, si = sched
    plant = example_fmu("two_link_payload")
    ref = inverse_dynamics_reference(d.plant, pl, DT, DURATION, 0.3)
    path = write_ssp(d, plant, tmp_path / "system.ssp", ref, schedule=s, integral=si)
    sensors = list(d.kalman.sensors)
    record = ["upper.tip.v", "fore.tip.v"]
    run_ = run_libcosim_ssp(path, len(ref.time) - 1, {PLANT: sensors + record, CONTROLLER: list(d.lqr.inputs)})
    assert run_.ok, run_.why + run_.log[-2000:]
    law = ScheduledPredictiveIntegralLQGLaw(si, [LIMIT, LIMIT], ref)
    with FmuLoop(plant, record=record) as loop:
        py = loop.run(JacobiDelay(law, law.initial()), ref)
    assert np.max(np.abs(law.xi)) > 1e-5
    for name in sensors + record:
        x = np.asarray(run_.values[f"{PLANT}:{name}"])          # after step k: t_1 … t_n
        scale = max(1.0, float(np.max(np.abs(py[name]))))
        print(f"\n  libcosim: {name} differs by {np.max(np.abs(x - py[name][1:])):.2g} (scale {scale:.3g})")
        assert np.max(np.abs(x - py[name][1:])) <= 1e-9 * scale, name
    for u in d.lqr.inputs:                                     # output after step k: applied over [t_k, t_k+1]
        x = np.asarray(run_.values[f"{CONTROLLER}:{u}"])
        print(f"  libcosim: {u} differs by {np.max(np.abs(x[:-1] - py[u][1:-1])):.2g} N m")
        assert np.max(np.abs(x[:-1] - py[u][1:-1])) <= 1e-9 * LIMIT, u
    errors = np.degrees([py[f"{j}.theta"][-1] - t for j, t in zip(JOINTS, TARGETS, strict=True)])
    print(f"  final joint errors {errors} deg")
    assert np.all(np.abs(errors) < 0.1)


def test_cli_exports_the_fmu_and_the_ssp(tmp_path, capsys):
    from flexlink.cli import main

    base = ["control", str(SCENE), "--design-only", "--torque-limit", "60", "--target", "60,90", "--duration", "1.5",
            "--integral", "0.5", "--schedule", "3"]
    assert main([*base, "--export-fmu", str(tmp_path / "c.fmu")]) == 0
    assert "scheduled at 3 poses with integral action" in capsys.readouterr().err
    assert main([*base, "--export-ssp", str(tmp_path / "s.ssp")]) == 0
    err = capsys.readouterr().err
    assert "scheduled at 3 poses with integral action (integral time 0.5 s)" in err
    read_ssd(str(tmp_path / "s.ssp"), validate=True)
