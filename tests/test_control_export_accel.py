"""The accelerometer LQG as a controller FMU and in the SSP package (issue 16, ``--sensors accelerometer``).

The law (:class:`controllers.multijoint.MimoLQGLaw` with the tip accelerometer) reads its sensors along the
manoeuvre: per sample the expected measurement, its rows C_k, D_k, the plant sampled along the reference
A_k, B_k and the time-varying Kalman gain M_k.  The controller FMU carries them as tables and plays the
manoeuvre itself.  Shown here, on the two-link arm (60°/20° in 1.5 s, the shoulder saturating) and on the
one-joint rotating link:

* fmpy validates the FMU and ``flexlink check`` passes it;
* fmpy stepping the plant FMU and the controller FMU equals, to 1e-9, the plant FMU with the same law in
  Python computed in the C's order of operations (:class:`COrderLaw`, written here from the law's own
  tables: a second implementation of the arithmetic).  Against :class:`MimoLQGLaw` itself (numpy's order of
  summation) the plant's states agree to 1e-9 too; the torques differ by the closed loop's amplification of
  rounding, which numpy alone shows: the same law with one sum reordered (:class:`Reordered`) differs from
  it by as much;
* the same with the gain scheduled over the path (``--schedule``);
* with the torque applied one sample late (a Jacobi master, the SSP package's controller built for it),
  libcosim running the package equals the Python loop to 1e-9;
* without a manoeuvre the export is refused with one message.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import EXAMPLES
from fmpy.validation import validate_fmu

from controllers.cosim import FmuLoop
from controllers.design import DesignError
from controllers.export import FmuLaw, export_controller_fmu
from controllers.manoeuvre import design
from controllers.multijoint import MimoLQGLaw, inverse_dynamics_reference, plan
from flexlink.mechanics.model import build_model
from flexlink.scene.loader import load_scene
from flexlink.tools.importers import libcosim_available

TWO_LINK = EXAMPLES / "two_link_payload.toml"
TARGETS = [math.radians(60.0), math.radians(20.0)]
DURATION, SETTLE, LIMIT = 1.5, 0.5, 60.0
RECORD = ["upper.tip.v", "fore.tip.v"]


class COrderLaw(MimoLQGLaw):
    """:class:`MimoLQGLaw` along its reference, each sum taken term by term in ``ctrl_fmu.c``'s order."""

    def step(self, y, x_ref, u_ff):
        k, sc, al = self.k, self.schedule, self.along
        M, A, B, W = al.M[k], al.A[k], al.B[k], al.W[k]
        n, p, m = len(self.dz), len(y), len(self.u0)
        C, D, yr, up = sc.C[k].tolist(), sc.D[k].tolist(), sc.y_ref[k].tolist(), sc.u_ff_prev[k].tolist()
        z, held = self.dz.tolist(), self.u_prev.tolist()
        innov = []
        for i in range(p):
            s = float(y[i]) - yr[i]
            for j in range(n):
                s -= C[i][j] * z[j]
            for j in range(m):
                s -= D[i][j] * (held[j] - up[j])
            innov.append(s)
        e = []
        for i in range(n):
            s = z[i]
            for j in range(p):
                s += float(M[i, j]) * innov[j]
            e.append(s)
        u = []
        for i in range(m):
            s = float(self.u0[i]) + float(u_ff[i])
            for j in range(n):
                s -= float(self.K[i, j]) * e[j]
            u.append(min(max(s, -float(self.limits[i])), float(self.limits[i])))
        nz = []
        for i in range(n):
            s = -float(W[i])
            for j in range(n):
                s += float(A[i, j]) * e[j]
            for j in range(m):
                s += float(B[i, j]) * (u[j] - float(self.u0[j]) - float(u_ff[j]))
            nz.append(s)
        self.dz = np.array(nz)
        self.u_prev = np.array(u) - self.u0
        self.k += 1
        return np.array(u)


class Reordered(MimoLQGLaw):
    """:class:`MimoLQGLaw` with the expected measurement's three terms summed in the other order."""

    def predicted(self, x_ref, C):
        sc, k = self.schedule, self.k
        return sc.D[k] @ (self.u_prev - sc.u_ff_prev[k]) + sc.C[k] @ self.dz + sc.y_ref[k]


def manoeuvre(scene, targets, duration, settle, limit):
    d = design(build_model(load_scene(scene)), torque_limit=limit, dt=1e-3, sensors="accelerometer")
    ref = inverse_dynamics_reference(d.plant, plan(d.plant, targets), d.dt, duration, settle)
    return d, ref


@pytest.fixture(scope="module")
def two_link(tmp_path_factory):
    d, ref = manoeuvre(TWO_LINK, TARGETS, DURATION, SETTLE, LIMIT)
    fmu = export_controller_fmu(d, tmp_path_factory.mktemp("acc") / "ctrl.fmu", reference=ref)
    return d, ref, fmu


def loops(plant, d, ref, fmu, limits, record):
    """The plant FMU with the controller FMU, with the law in the C's order, with the law itself, reordered."""
    ctrl = FmuLaw(fmu, builtin=True)
    try:
        with FmuLoop(plant, record=record) as loop:
            runs = {"fmu": loop.run(ctrl, ref), "fmu again": loop.run(ctrl, ref)}
            for name, cls in (("c order", COrderLaw), ("numpy", MimoLQGLaw), ("reordered", Reordered)):
                runs[name] = loop.run(cls(d, limits, ref), ref)
    finally:
        ctrl.close()
    return runs


def difference(a, b, names):
    return {n: float(np.max(np.abs(a[n] - b[n]))) for n in names}


#: How much the accelerometer loop along the reference grows a perturbation over its first samples, from its
#: linearisation (the law in loop with its own time-varying model; docs/control.md): about 3e6.
LOOP_AMPLIFICATION = 3e6


def rounding_bound(run, torques) -> float:
    """What rounding alone can move a torque by in this loop: a sample's sums (about 16 roundings of ε, relative to
    the largest torque) grown by LOOP_AMPLIFICATION.  One reordering of numpy's sums is one draw of it (measured
    2e-9 to 7e-8 N m from run to run), too variable to bound another draw by itself."""
    scale = max(float(np.max(np.abs(run[u]))) for u in torques)
    return 16 * np.finfo(float).eps * LOOP_AMPLIFICATION * scale


def check_loops(runs, d, record) -> dict:
    torques, states = list(d.lqr.inputs), [f"{j}.theta" for j in d.actuated_joints] + record
    names = list(d.kalman.sensors) + states + torques
    fmu = runs["fmu"]
    for n in names:
        np.testing.assert_array_equal(runs["fmu again"][n], fmu[n])       # fmi2Reset between runs
    same = difference(fmu, runs["c order"], names)
    numpy = difference(fmu, runs["numpy"], names)
    spread = difference(runs["reordered"], runs["numpy"], names)
    print(f"\n|FMU - law in C order| {same}\n|FMU - MimoLQGLaw| {numpy}\n|reordered - MimoLQGLaw| {spread}")
    for n in names:
        scale = max(1.0, float(np.max(np.abs(fmu[n]))))
        assert same[n] <= 1e-9 * scale, n
    for n in states:
        assert numpy[n] <= 1e-9 * max(1.0, float(np.max(np.abs(fmu[n])))), n
    # the torques: the FMU is as far from numpy's law as numpy's own rounding (reordering one sum) moves it
    assert max(numpy[u] for u in torques) <= rounding_bound(fmu, torques)
    return {"c_order": same, "numpy": numpy, "numpy_reordered": spread}


def test_fmpy_validate_and_flexlink_check(two_link, tmp_path):
    from flexlink.cli import main

    d, ref, fmu = two_link
    assert validate_fmu(str(fmu)) == []
    assert main(["check", str(fmu), "--report", str(tmp_path / "check")]) == 0


def test_two_link_closed_loop_equals_the_law(two_link, example_fmu):
    d, ref, fmu = two_link
    runs = loops(example_fmu("two_link_payload"), d, ref, fmu, [LIMIT, LIMIT], RECORD)
    check_loops(runs, d, RECORD)
    fmu_run = runs["fmu"]
    assert np.max(np.abs(fmu_run["shoulder.tau"])) == LIMIT          # the saturation is exercised
    for j, target in zip(("shoulder", "elbow"), TARGETS, strict=True):
        assert abs(math.degrees(fmu_run[f"{j}.theta"][-1] - target)) < 1e-2


def test_one_joint_closed_loop_equals_the_law(tmp_path, example_fmu):
    """The rotating link (one joint, seed 000's link): 30° in 1 s, the accelerometer on its tip."""
    d, ref = manoeuvre(EXAMPLES / "rotating_link.toml", [math.radians(30.0)], 1.0, 1.5, 5.0)
    assert d.actuated_joints == ["hub"] and d.kalman.sensors == ["hub.theta", "tip.sx", "tip.sy"]
    fmu = export_controller_fmu(d, tmp_path / "ctrl.fmu", reference=ref)
    assert validate_fmu(str(fmu)) == []
    runs = loops(example_fmu("rotating_link"), d, ref, fmu, [5.0], ["arm.tip.v"])
    check_loops(runs, d, ["arm.tip.v"])
    assert abs(math.degrees(runs["fmu"]["hub.theta"][-1]) - 30.0) < 1e-2


def test_scheduled_accelerometer_fmu(tmp_path, example_fmu):
    """``--schedule 3 --sensors accelerometer``: the LQR gain scheduled over the path (elbow −20° → 90°), the
    accelerometer read along the reference, in the C as :class:`controllers.schedule.ScheduledLQGLaw`: the
    plant's states to 1e-9, the torques within numpy's own rounding spread (the law reordered)."""
    from controllers.schedule import ScheduledLQGLaw, design_schedule

    class ScheduledReordered(ScheduledLQGLaw):
        predicted = Reordered.predicted

    targets = [math.radians(60.0), math.radians(90.0)]
    d, ref = manoeuvre(TWO_LINK, targets, DURATION, SETTLE, LIMIT)
    schedule = design_schedule(d, plan(d.plant, targets), 3)
    fmu = export_controller_fmu(d, tmp_path / "ctrl.fmu", reference=ref, schedule=schedule, duration=DURATION)
    ctrl = FmuLaw(fmu, builtin=True)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=RECORD) as loop:
            b = loop.run(ctrl, ref)
            a = loop.run(ScheduledLQGLaw(schedule, [LIMIT, LIMIT], ref), ref)
            r = loop.run(ScheduledReordered(schedule, [LIMIT, LIMIT], ref), ref)
    finally:
        ctrl.close()
    states, torques = ["shoulder.theta", "elbow.theta", *RECORD], list(d.lqr.inputs)
    got, spread = difference(b, a, states + torques), difference(r, a, torques)
    print(f"\n|FMU - ScheduledLQGLaw| {got}\n|reordered - ScheduledLQGLaw| {spread}")
    for n in states:
        assert got[n] <= 1e-9 * max(1.0, float(np.max(np.abs(a[n])))), n
    assert max(got[u] for u in torques) <= rounding_bound(b, torques)
    assert abs(math.degrees(b["elbow.theta"][-1] - targets[1])) < 1e-2


def test_after_its_reference_the_fmu_holds_the_targets(two_link, example_fmu):
    """Stepped 1 s past the end of its tables (the manoeuvre and 0.5 s), the controller FMU keeps their last
    rows (the linearisation at rest at the targets, the filter's last gain): the arm stays at the targets
    with the torques that hold it there (:func:`controllers.multijoint.plan`'s static residual)."""
    d, ref, fmu = two_link
    pl = plan(d.plant, TARGETS)
    longer = inverse_dynamics_reference(d.plant, pl, d.dt, DURATION, SETTLE + 1.0)
    ctrl = FmuLaw(fmu, builtin=True)
    try:
        with FmuLoop(example_fmu("two_link_payload"), record=RECORD) as loop:
            res = loop.run(ctrl, longer)
    finally:
        ctrl.close()
    n, last = len(ref.time), slice(-200, None)                  # the tables' end, the last 0.2 s
    for k, (j, target) in enumerate(zip(("shoulder", "elbow"), TARGETS, strict=True)):
        err = np.abs(np.degrees(res[f"{j}.theta"] - target))
        tau = np.abs(res[f"{j}.tau"] - pl.u_end[k])
        print(f"\n{j}: |error| {err[n]:.2e} deg at the tables' end, <= {np.max(err[last]):.2e} deg over the last "
              f"0.2 s; |torque - holding| {tau[n]:.2e} → {np.max(tau[last]):.2e} N m")
        assert np.max(err[last]) < 1e-3 and np.max(err[last]) < err[n]
        assert np.max(tau[last]) < 1e-3 * LIMIT


def test_refusals(two_link, tmp_path):
    """Without its manoeuvre the accelerometer's controller FMU is refused; a NaN measurement is an error."""
    import fmpy
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    d, ref, fmu = two_link
    with pytest.raises(DesignError, match="along the manoeuvre's reference .* give --target and --duration"):
        export_controller_fmu(d, tmp_path / "no_reference.fmu")
    assert not (tmp_path / "no_reference.fmu").exists()
    md = fmpy.read_model_description(str(fmu))
    s = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(str(fmu)),
                  modelIdentifier=md.coSimulation.modelIdentifier)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    with pytest.raises(FMICallException):
        s.setReal([2], [math.nan])                     # tip.sx
    with pytest.raises(FMICallException):
        s.doStep(0.0, 2 * d.dt)
    s.doStep(0.0, d.dt)
    s.terminate()
    s.freeInstance()


SSP_TARGETS = [math.radians(5.0), math.radians(-15.0)]     # shoulder 0 → 5°, elbow −20° → −15° in 1 s


@pytest.mark.skipif(not libcosim_available(), reason="libcosimpy is not installed")
def test_libcosim_runs_the_accelerometer_package_as_python(tmp_path, example_fmu):
    """The SSP package with the accelerometer's controller (predictive, for libcosim's one sample of delay):
    libcosim's run equals the plant FMU with the Python law applied as a Jacobi master applies it, to 1e-9.

    A smaller manoeuvre than above: with the torque applied one sample late the accelerometer LQG holds this
    one, while from 10°/10° in 1 s on it chatters between the torque limits, in Python as in libcosim
    (docs/control.md)."""
    from controllers.ssp import CONTROLLER, PLANT, JacobiDelay, JacobiLoop, PredictiveLQGLaw, write_ssp
    from flexlink.tools.importers import run_libcosim_ssp

    d, ref = manoeuvre(TWO_LINK, SSP_TARGETS, 1.0, 0.5, LIMIT)
    plant = example_fmu("two_link_payload")
    path = write_ssp(d, plant, tmp_path / "system.ssp", ref)
    sensors, torques = list(d.kalman.sensors), list(d.lqr.inputs)
    run = run_libcosim_ssp(path, len(ref.time) - 1, {PLANT: sensors + RECORD, CONTROLLER: torques})
    assert run.ok, run.why + run.log[-2000:]
    law = PredictiveLQGLaw(d, [LIMIT, LIMIT], ref)
    with JacobiLoop(plant, record=RECORD) as loop:
        py = loop.run(JacobiDelay(law, law.initial()), ref)
    worst = {}
    for name in sensors + RECORD:                              # after step k: t_1 … t_n
        x = np.asarray(run.values[f"{PLANT}:{name}"])
        worst[name] = float(np.max(np.abs(x - py[name][1:])))
        assert worst[name] <= 1e-9 * max(1.0, float(np.max(np.abs(py[name])))), name
    for u in torques:                                          # output after step k: applied over [t_k, t_k+1]
        x = np.asarray(run.values[f"{CONTROLLER}:{u}"])
        worst[u] = float(np.max(np.abs(x[:-1] - py[u][1:-1])))
        assert worst[u] <= 1e-9 * LIMIT, u
    print(f"\n|libcosim - Python| {worst}")
    for j, target in zip(("shoulder", "elbow"), SSP_TARGETS, strict=True):
        assert abs(math.degrees(py[f"{j}.theta"][-1] - target)) < 1e-2


def test_cli_exports_the_accelerometer_controller(tmp_path, capsys):
    from flexlink.cli import main

    out = tmp_path / "acc.fmu"
    base = ["control", str(TWO_LINK), "--design-only", "--torque-limit", str(LIMIT), "--sensors", "accelerometer"]
    assert main([*base, "--target", "60,20", "--duration", "1.5", "--settle", "0.2", "--export-fmu", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"wrote {out}" in err and "playing the manoeuvre (1.7 s)" in err and validate_fmu(str(out)) == []
    assert main([*base, "--export-fmu", str(tmp_path / "none.fmu")]) == 2
    err = capsys.readouterr().err
    assert "give --target and --duration" in err and err.count("\n") == 1 and not (tmp_path / "none.fmu").exists()
