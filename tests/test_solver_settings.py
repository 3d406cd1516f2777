"""The solver settings' one owner (flexlink.scene.solver) against the C glue that applies them.

The FMU's checks at fmi2SetReal/fmi2ExitInitializationMode are C code of their own (fmu_src/instance.c,
variables.c); the Python rule is compared with them setting by setting, so the two cannot drift apart.  The
header fmu_src/solver_settings.h is written from the Python module and must equal what it writes.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zipfile

import pytest

from flexlink.export import solver_header
from flexlink.export.cbuild import fmu_src_dir
from flexlink.run.simulate import SlaveRunner
from flexlink.scene import solver
from flexlink.scene.solver import SolverSettings


def test_the_c_header_is_the_one_written_from_the_python_owner() -> None:
    written = (fmu_src_dir() / solver_header.HEADER).read_text()
    assert written == solver_header.render(), "run: python -m flexlink.export.solver_header"


def test_the_c_glue_has_no_hand_copy_of_the_limits() -> None:
    """The limits are defined once, in the generated header, and nowhere else in the fixed C."""
    for path in fmu_src_dir().glob("*.[ch]"):
        if path.name == solver_header.HEADER:
            continue
        text = path.read_text()
        for name in ("SUBSTEP_MAX", "DOSTEP_MAX_INTERNAL_STEPS", "RICHARDSON_MAX_OMEGA_STEP", "N_SOLVER_SETTINGS",
                     "SS22_MAX_ITERATIONS", "SS22_ROUNDING_FACTOR", "STATIC_MAX_ITERATIONS"):
            assert f"#define {name}" not in text and f"{name}\n}} SolverSetting" not in text, (path.name, name)


def test_the_c_messages_print_the_limits_rather_than_spell_them() -> None:
    """A message that spells a limit as text ("must be 2 (SS22) or 4", "= 0.5") would go stale when the owner
    changes it: the C string literals print the generated values instead."""
    import re

    spelled = [f"or {solver.ORDER_RICHARDSON}", f"solver.order = {solver.ORDER_RICHARDSON}",
               f"order {solver.ORDER_SS22},", f"%s = {solver.THETA_MIN:g}", f"{solver.THETA_MIN:g} <= %s",
               f"%s <= {solver.THETA_MAX:g}"]
    for path in fmu_src_dir().glob("*.c"):
        for literal in re.findall(r'"((?:[^"\\\n]|\\.)*)"', path.read_text()):
            assert not [t for t in spelled if t in literal], (path.name, literal)


def test_the_fmu_refusals_name_the_owner_limits(example_fmu) -> None:
    """What the FMU says when it refuses a setting carries the owner's numbers (printed from the header)."""
    from flexlink.run.host import FmuCallError, FmuHost

    order_rule = f"must be {solver.ORDER_SS22} (SS22) or {solver.ORDER_RICHARDSON} (SS22 with Richardson"
    theta_rule = f"SS22 needs {solver.THETA_MIN:g} <= solver.theta1 <= solver.theta2 <= {solver.THETA_MAX:g}"
    symmetric = (f"solver.order = {solver.ORDER_RICHARDSON} extrapolates the symmetric SS22: it needs "
                 f"solver.theta1 = solver.theta2 = {solver.THETA_MIN:g}, got 0.6 and 0.6")
    with FmuHost(example_fmu("rotating_link")) as host:
        for start, rule in (({"solver.order": 3}, order_rule), ({"solver.theta1": 0.8, "solver.theta2": 0.6},
                                                                 theta_rule),
                            ({"solver.order": 4, "solver.theta1": 0.6, "solver.theta2": 0.6}, symmetric)):
            with pytest.raises(FmuCallError) as info:
                host.initialize(start)
            assert rule in info.value.reason, (start, info.value.reason)


CASES = [
    # step, (theta1, theta2), tolerance, order
    (1e-3, (0.5, 0.5), 1e-10, 2),
    (2e-4, (0.6, 0.9), 1e-8, 2),
    (1e-3, (1.0, 1.0), 1e-6, 2),
    (1e-3, (0.5, 0.5), 1e-10, 4),
    (1e-3, (0.4, 0.5), 1e-10, 2),
    (1e-3, (0.8, 0.6), 1e-10, 2),
    (1e-3, (0.5, 1.1), 1e-10, 2),
    (1e-3, (0.6, 0.6), 1e-10, 4),
    (1e-3, (0.5, 0.5), 1e-10, 3),
    (1e-3, (0.5, 0.5), 0.0, 2),
    (-1e-3, (0.5, 0.5), 1e-10, 2),
]


def _python_accepts(step, theta, tolerance, order) -> bool:
    try:
        SolverSettings(step=step, theta=theta, tolerance=tolerance, order=order)
    except ValueError:
        return False
    return True


def _fmu_accepts(runner: SlaveRunner, step, theta, tolerance, order) -> bool:
    start = {"solver.step": step, "solver.theta1": theta[0], "solver.theta2": theta[1],
             "solver.tolerance": tolerance, "solver.order": order}
    try:
        runner.run(0.004, 0.002, start=start, outputs=["hub.theta"])
    except Exception:   # fmpy raises on fmi2Error (a set refused, or exit-initialisation refused)
        return False
    return True


def test_python_and_the_fmu_accept_the_same_settings(example_fmu) -> None:
    fmu = example_fmu("rotating_link")
    verdicts = []
    for case in CASES:
        with SlaveRunner(fmu) as runner:
            verdicts.append((case, _python_accepts(*case), _fmu_accepts(runner, *case)))
    assert [v for v in verdicts if v[1] != v[2]] == []
    assert sum(v[1] for v in verdicts) == 4     # the four valid cases above, and no other


def test_the_fmu_declares_the_owner_defaults_and_bounds(example_fmu) -> None:
    """The model description's solver.* variables: the scene's settings as start values, the owner's ranges."""
    with zipfile.ZipFile(example_fmu("rotating_link")) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    variables = {v.get("name"): v for v in root.iter("ScalarVariable")}
    defaults = SolverSettings()        # examples/rotating_link.toml has no [fmu] solver keys
    for setting in solver.SETTINGS:
        element = next(iter(variables[setting.name]))
        assert element.tag == ("Integer" if setting.integer else "Real")
        assert float(element.get("start")) == pytest.approx(defaults.start_values()[setting.name], rel=0)
        if setting.max < float("inf"):
            assert float(element.get("max")) == setting.max
    step = float(root.find("DefaultExperiment").get("stepSize"))
    assert step == max(defaults.step, solver.MIN_DEFAULT_COMMUNICATION_STEP)
