"""Co-simulation at 1 ms communication steps through fmpy (issue 6, item 2): three ways to step the same model.

    python benchmarks/cosim_loop.py [SCENE.toml ...] [--comm-step H] [--repeats N] [--quick] [--json]

Issue 6's manoeuvre (+τ for 1 s, −τ for 1 s, then free, 5 s) driven from a Python loop that, at every
communication point, sets the torque, advances one communication step and reads the outputs:

* ``flexlink FMU``: the scene's FMU through fmpy's ``FMU2Slave`` on flexlink's FmuHost (setReal, doStep,
  getReal), SS22 at several internal steps and the order-4 option;
* ``python FMU``: a PythonFMU 0.7 FMU (``benchmarks/python_fmu_slave.py``) integrating the same equations by
  RK4 in one CasADi call per step, through the very same fmpy loop;
* ``cvodes per step``: CasADi's CVODES restarted at every communication step (``ca.integrator`` over one step,
  called once per step from Python with the last state; outputs computed afterwards, not charged).

Times are CPU seconds of the loop per simulated second (medians of ``--repeats``); errors are relative RMS
deviations of the first joint angle and the tip deflection from CVODES at rtol 1e-12, at 10 ms samples, as in
``flexlink bench``.  "At equal error" compares the cheapest row of each method that is at least as accurate.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SLAVE = Path(__file__).resolve().parent / "python_fmu_slave.py"
DEFAULT = ["rotating_link_linear.toml", "rotating_link.toml"]
SUBSTEPS = (1, 2, 4)

OURS, PYFMU, CVODES = "flexlink FMU", "python FMU (RK4)", "cvodes per step"


def build_python_fmu(model, outputs: list[str], path: str | Path, substeps=SUBSTEPS) -> Path:
    """A PythonFMU FMU of ``model`` (inputs: the model's FMU inputs; outputs: ``outputs``), integrating by RK4."""
    import casadi as ca
    from pythonfmu import FmuBuilder

    from flexlink.tools.bench import _ode

    x, u, p, ode = _ode(model)
    f = ca.Function("f", [x, u, p], [ode])
    n = model.n_q
    a = ode[n:]                                    # the acceleration: M(q) a = -r(q, v, 0, u, p)
    y_all = model.outputs_function(x[:n], x[n:], a, u, p)
    y = ca.vertcat(*[y_all[model.output_index(name)] for name in outputs])
    h = ca.SX.sym("h")
    path = Path(path)
    inputs = [s.name for s in model.inputs]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = []
        for k in substeps:
            xk = x
            dt = h / k
            for _ in range(k):
                k1 = f(xk, u, p)
                k2 = f(xk + dt / 2 * k1, u, p)
                k3 = f(xk + dt / 2 * k2, u, p)
                k4 = f(xk + dt * k3, u, p)
                xk = xk + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            yk = ca.substitute(y, x, xk)
            F = ca.Function(f"step_{k}", [x, u, p, h], [xk, yk]).expand()
            F.save(str(tmp / f"step_{k}.casadi"))
            files.append(tmp / f"step_{k}.casadi")
        meta = {"x0": np.concatenate(model.start_state()).tolist(), "p0": np.asarray(model.p0).tolist(),
                "u0": np.asarray(model.default_inputs(0.0)).tolist(), "inputs": inputs, "outputs": outputs,
                "substeps": list(substeps)}
        (tmp / "flexlink_py.json").write_text(json.dumps(meta))
        files.append(tmp / "flexlink_py.json")
        path.parent.mkdir(parents=True, exist_ok=True)
        FmuBuilder.build_FMU(SLAVE, dest=path, project_files=files)
    return path


def fmpy_loop(fmu: str | Path, case, comm_step: float, start: dict, repeats: int) -> tuple[float, dict]:
    """The host loop (setReal, doStep, getReal at every communication point) over ``case``; returns the median
    CPU seconds per simulated second and the outputs at ``case.times``.  The instance is the project's one FMU
    host (flexlink.run.host.FmuHost); the loop calls fmpy's FMU2Slave methods on it, as an fmpy user would."""
    from flexlink.run.host import FmuHost

    n = int(round(case.stop / comm_step))
    times = np.arange(n + 1) * comm_step
    input_names = sorted({k for _, values in case.pieces for k in values})
    u_at = [[case.inputs_at(t).get(name, 0.0) for name in input_names] for t in times]
    cpu, Y = [], None
    with FmuHost(fmu, instance_name="loop") as host:
        s = host.instance
        vr_out = [host.value_reference(name) for name in case.outputs]
        vr_in = [host.value_reference(name) for name in input_names]
        for _ in range(repeats):
            host.initialize(start)                    # each start value through its type's setter
            rows = [s.getReal(vr_out)]
            t0 = time.process_time()
            for k in range(n):
                s.setReal(vr_in, u_at[k])
                s.doStep(times[k], comm_step)
                rows.append(s.getReal(vr_out))
            cpu.append(time.process_time() - t0)
            Y = np.array(rows)
    idx = np.searchsorted(times, case.times - 1e-9)
    return statistics.median(cpu) / case.stop, {name: Y[idx, j] for j, name in enumerate(case.outputs)}


def cvodes_per_step(case, comm_step: float, tol: float, repeats: int) -> tuple[float, dict]:
    """CasADi's CVODES restarted at every communication step, called from a Python loop."""
    import casadi as ca

    from flexlink.tools.bench import _model_inputs, _ode, _outputs

    x, u, p, ode = _ode(case.model)
    F = ca.integrator("step", "cvodes", {"x": x, "p": ca.vertcat(u, p), "ode": ode}, 0.0, comm_step,
                      {"abstol": tol * 1e-3, "reltol": tol, "max_num_steps": 10**7})
    n = int(round(case.stop / comm_step))
    times = np.arange(n + 1) * comm_step
    p_at = [ca.DM(np.concatenate([_model_inputs(case, float(t)), case.model.p0])) for t in times]
    x0 = ca.DM(np.concatenate(case.model.start_state()))
    cpu = []
    for _ in range(repeats):
        xs = [x0]
        xk = x0
        t0 = time.process_time()
        for k in range(n):
            xk = F(x0=xk, p=p_at[k])["xf"]
            xs.append(xk)
        cpu.append(time.process_time() - t0)
    idx = np.searchsorted(times, case.times - 1e-9)
    X = np.array([np.asarray(xs[i]).ravel() for i in idx])
    return statistics.median(cpu) / case.stop, _outputs(case, X)


def cost_at(rows: list[dict], method: str, error: float) -> dict | None:
    """The cheapest row of ``method`` at least as accurate as ``error`` (None: no row is)."""
    ok = [r for r in rows if r["method"] == method and r["error"] <= error * (1 + 1e-9)]
    return min(ok, key=lambda r: r["cpu_s_per_simulated_s"]) if ok else None


def equal_error_table(rows: list[dict]) -> list[dict]:
    """For every row of ours: the cheapest CVODES-per-step and Python-FMU rows reaching its error, and ratios."""
    out = []
    for r in rows:
        if r["method"] != OURS:
            continue
        entry = {"setting": r["setting"], "error": r["error"], "ours": r["cpu_s_per_simulated_s"]}
        for method, key in ((CVODES, "cvodes"), (PYFMU, "python_fmu")):
            other = cost_at(rows, method, r["error"])
            entry[key] = other["cpu_s_per_simulated_s"] if other else None
            entry[f"{key}_setting"] = other["setting"] if other else None
            entry[f"{key}_ratio"] = other["cpu_s_per_simulated_s"] / r["cpu_s_per_simulated_s"] if other else None
        out.append(entry)
    return out


def run_cosim(scene_path, *, quick: bool = False, repeats: int | None = None, comm_step: float = 1e-3,
              fmu: str | Path | None = None, workdir: str | Path | None = None) -> tuple[list[dict], dict]:
    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.model import build_model
    from flexlink.scene.loader import load_scene
    from flexlink.tools.bench import default_case, reference_outputs, relative_error

    scene = load_scene(scene_path)
    model = build_model(scene)
    case = default_case(model, stop=0.5 if quick else 5.0)
    repeats = repeats or (1 if quick else 5)
    ref = reference_outputs(case, 1e-12)
    rows: list[dict] = []

    def add(method, setting, cpu, y):
        rows.append({"method": method, "setting": setting, "cpu_s_per_simulated_s": cpu,
                     "us_per_comm_step": 1e6 * cpu * comm_step, "error": relative_error(case, y, ref)})

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(workdir or tmp)
        if fmu is None:
            fmu = build_fmu(scene, work / f"{scene.model_identifier}.fmu", model=model).fmu
        ours = [(2, comm_step), (2, comm_step / 4)] if quick else \
            [(2, comm_step), (2, comm_step / 2), (2, comm_step / 4), (2, comm_step / 8), (2, comm_step / 16),
             (4, comm_step), (4, comm_step / 2), (4, comm_step / 4)]
        for order, h in ours:
            cpu, y = fmpy_loop(fmu, case, comm_step, {"solver.step": h, "solver.order": order}, repeats)
            add(OURS, f"step={h:g}" + (", order 4" if order == 4 else ""), cpu, y)
        pyfmu = build_python_fmu(model, case.outputs, work / "python_fmu.fmu")
        for k in ((1, 2) if quick else SUBSTEPS):
            cpu, y = fmpy_loop(pyfmu, case, comm_step, {"solver.substeps": k}, repeats)
            add(PYFMU, f"RK4 step={comm_step / k:g}", cpu, y)
        tols = [1e-4, 1e-7] if quick else [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9]
        for tol in tols:
            cpu, y = cvodes_per_step(case, comm_step, tol, max(1, repeats if quick else min(repeats, 3)))
            add(CVODES, f"rtol={tol:g}", cpu, y)
    info = {"scene": str(scene_path), "comm_step": comm_step, "stop_time": case.stop, "outputs": case.outputs,
            "reference_error": relative_error(case, ref, reference_outputs(case, 1e-13)),
            "equal_error": equal_error_table(rows)}
    return rows, info


def format_rows(rows: list[dict], info: dict) -> str:
    lines = [f"{info['scene']}: {info['comm_step'] * 1e3:g} ms communication steps through fmpy, "
             f"{info['stop_time']:g} s", f"{'method':20s} {'setting':24s} {'CPU s/sim s':>11s} {'us/step':>8s} "
             f"{'error':>9s}"]
    for r in rows:
        lines.append(f"{r['method']:20s} {r['setting']:24s} {r['cpu_s_per_simulated_s']:11.4g} "
                     f"{r['us_per_comm_step']:8.1f} {r['error']:9.2e}")
    lines.append("at equal error (cheapest row at least as accurate): ratio = its cost / ours")
    def fmt(e, key):
        return "not reached" if e[f"{key}_ratio"] is None else f"{e[f'{key}_ratio']:.1f}x ({e[f'{key}_setting']})"

    for e in info["equal_error"]:
        lines.append(f"  ours {e['setting']:20s} error {e['error']:.2e}: cvodes per step {fmt(e, 'cvodes')}, "
                     f"python FMU {fmt(e, 'python_fmu')}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--comm-step", type=float, default=1e-3)
    ap.add_argument("--repeats", type=int)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    scenes = args.scenes or [str(ROOT / "examples" / s) for s in DEFAULT]
    out = []
    for path in scenes:
        rows, info = run_cosim(path, quick=args.quick, repeats=args.repeats, comm_step=args.comm_step)
        out.append({"rows": rows, "info": info})
        if not args.json:
            print(format_rows(rows, info))
    if args.json:
        print(json.dumps(out))


if __name__ == "__main__":
    main()
