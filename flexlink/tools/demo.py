"""The README's main job: build the seed-000 rotating-link FMU and run it through fmpy.

It prints the build figures, the link's natural frequencies, and a bang-bang torque manoeuvre
(+0.2 N m for 1 s, −0.2 N m for 1 s, then free, as in the benchmark issue) compared with the CVODES
reference simulation of the same model, and writes a plot.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "rotating_link.toml"


def run_demo(out: str | Path = "out") -> int:
    """Build the example FMU, run it, compare it with CVODES, and write its plot and CSV into ``out``."""
    import fmpy

    from flexlink.export.fmu import build_fmu
    from flexlink.mechanics.analysis import natural_frequencies
    from flexlink.mechanics.model import build_model
    from flexlink.mechanics.reference import simulate_reference
    from flexlink.run.simulate import plot_result, simulate, variable_units, write_csv
    from flexlink.scene.loader import load_scene

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene = load_scene(EXAMPLE)
    model = build_model(scene)
    rep = build_fmu(scene, out / "rotating_link.fmu", model=model)
    print(f"built {rep.fmu} in {sum(rep.seconds.values()):.2f} s: {rep.n_coordinates} coordinates, "
          f"{rep.fmu_bytes / 1024:.0f} KiB")
    modes = natural_frequencies(model)
    print("natural frequencies (Hz):", ", ".join(f"{f:.4g}" for f in modes.frequencies_hz))

    stop, step = 5.0, scene.fmu.solver.step
    torque = np.array([(0.0, 0.2), (1.0, 0.2), (1.0, -0.2), (2.0, -0.2), (2.0, 0.0), (stop, 0.0)],
                      dtype=[("time", float), ("hub.tau", float)])
    t0 = time.perf_counter()
    shown = ["hub.tau", "hub.theta", "hub.omega", "arm.tip.v", "arm.root.moment"]
    res = simulate(rep.fmu, stop, step=0.01, inputs=torque, start_values={"solver.step": step},
                   outputs=shown)
    wall = time.perf_counter() - t0
    times = res["time"]
    ref = simulate_reference(model, times, inputs=[(0.0, {"hub.tau": 0.2}), (1.0, {"hub.tau": -0.2}),
                                                   (2.0, {"hub.tau": 0.0})])
    err_theta = np.max(np.abs(res["hub.theta"] - ref.output(model, "hub.theta")))
    err_tip = np.max(np.abs(res["arm.tip.v"] - ref.output(model, "arm.tip.v")))
    write_csv(res, out / "rotating_link.csv")
    units = variable_units(fmpy.read_model_description(str(rep.fmu)))
    plot_result(res, out / "rotating_link.png", shown, units=units,
                title="seed-000 rotating link, bang-bang torque (FMU through fmpy)")
    print(f"FMU run: {stop} s simulated in {wall:.3f} s wall (SS22 step {step} s, communication step 0.01 s)")
    print(f"final hub angle {res['hub.theta'][-1]:.6f} rad, max |tip deflection| "
          f"{np.max(np.abs(res['arm.tip.v'])) * 1e3:.3f} mm")
    print(f"max deviation from the CVODES reference: hub angle {err_theta:.2e} rad, tip {err_tip:.2e} m")
    print(f"wrote {out / 'rotating_link.png'} and {out / 'rotating_link.csv'}")
    return 0
