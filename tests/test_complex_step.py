"""The forward derivatives by the complex step (fmu_src/complex_step.c) against CasADi's forward mode.

Two independent implementations of fmi2GetDirectionalDerivative: the FMU of the generated residual and
outputs evaluated in complex arithmetic, and an FMU of the same scene built with CasADi's forward-mode
functions instead (``codegen.COMPLEX_STEP = False``, the form a model with a non-analytic operation keeps).
Their full Model Exchange Jacobians (state derivatives and outputs, in the states and the inputs) agree to
round-off (1e-13 of a row, up to 2.6e-10 where the row is a difference of much larger terms) at states away
from the start, on a free joint under gravity (sin/cos of a joint angle) and on a
spatial arm of rigid and flexible links.  That the complex step leaves the derivative code out is what it
is for (issue 15's code size): the units of the two builds say so.
"""

from __future__ import annotations

import ctypes
import zipfile
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Model

from flexlink.export import codegen
from flexlink.export.derivatives import complex_step_applies
from flexlink.export.fmu import build_fmu

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCENES = ["flexible_pendulum", "six_axis_arm"]


@pytest.fixture(scope="module")
def forward_mode_fmus(tmp_path_factory):
    """The scenes' FMUs with CasADi's forward-mode derivative functions (outside the build cache)."""
    built = {}
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(codegen, "COMPLEX_STEP", False)
        for name in SCENES:
            folder = tmp_path_factory.mktemp(name)
            built[name] = build_fmu(EXAMPLES / f"{name}.toml", folder).fmu
    return built


def _units(fmu: Path) -> set[str]:
    with zipfile.ZipFile(fmu) as z:
        return {Path(n).name for n in z.namelist() if n.startswith("sources/") and n.endswith(".c")}


def _parameters_moved(fmu: Path, rng: np.random.Generator) -> dict[int, float]:
    """Every real model parameter (the solver's settings left out), moved 5-15 % from its start (value
    reference → value).

    The complex twins read the parameters through their own argument: a twin that saw the start values, or
    none, would still agree with forward mode at the start values, not here.
    """
    md = read_model_description(str(fmu))
    moved, factors = {}, {}
    for v in md.modelVariables:
        if (v.causality == "parameter" and v.type == "Real" and not v.name.startswith("solver.")
                and v.start not in (None, "") and float(v.start) != 0):
            # one factor for a body's whole inertia tensor, which keeps its triangle inequalities
            group = v.name.rsplit(".", 1)[0] if ".inertia" in v.name else v.name
            if group not in factors:
                factors[group] = 1 + rng.choice([-1, 1]) * rng.uniform(0.05, 0.15)
            moved[v.valueReference] = float(v.start) * factors[group]
    return moved


def _jacobian_at(fmu: Path, offsets: np.ndarray, parameters: dict[int, float]) -> np.ndarray:
    """∂(ẋ, y)/∂(x, u) by fmi2GetDirectionalDerivative (Model Exchange) at the start state plus ``offsets``,
    with ``parameters`` (value reference → value) set before initialisation."""
    md = read_model_description(str(fmu))
    unzipped = extract(str(fmu))
    inst = FMU2Model(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.modelExchange.modelIdentifier,
                     instanceName="jacobian")
    inst.instantiate()
    try:
        inst.setupExperiment(startTime=0.0)
        if parameters:
            inst.setReal(list(parameters), list(parameters.values()))
        inst.enterInitializationMode()
        inst.exitInitializationMode()
        inst.enterContinuousTimeMode()
        n = len(md.derivatives)
        x = np.zeros(n)
        inst.getContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), n)
        x += offsets
        inst.setContinuousStates(x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), n)
        states = [d.variable.derivative.valueReference for d in md.derivatives]
        inputs = [v.valueReference for v in md.modelVariables if v.causality == "input"]
        unknown = [d.variable.valueReference for d in md.derivatives]
        unknown += [o.variable.valueReference for o in md.outputs]
        return np.column_stack([inst.getDirectionalDerivative(unknown, [k], [1.0]) for k in states + inputs])
    finally:
        inst.terminate()
        inst.freeInstance()


@pytest.mark.parametrize("name", SCENES)
def test_complex_step_equals_casadi_forward_mode(example_fmu, forward_mode_fmus, name):
    by_complex_step, by_forward_mode = example_fmu(name), forward_mode_fmus[name]
    # the complex step's build carries no derivative code, only the two small complex twins
    assert {u for u in _units(by_forward_mode) if u.endswith("forward.c")} == {
        f"{name}_forward.c", f"{name}_outputs_acceleration_forward.c"}
    assert not any(u.endswith("forward.c") for u in _units(by_complex_step))
    assert {f"{name}_residual_complex.c", f"{name}_outputs_complex.c"} <= _units(by_complex_step)
    n = len(read_model_description(str(by_complex_step)).derivatives)
    rng = np.random.default_rng(7)
    parameters = _parameters_moved(by_complex_step, rng)
    assert parameters == _parameters_moved(by_forward_mode, np.random.default_rng(7))   # the same variables
    assert len(parameters) >= 3
    for _ in range(2):
        offsets = 1e-3 * rng.standard_normal(n)     # joint angles, deflections and rates away from rest
        J_cs = _jacobian_at(by_complex_step, offsets, parameters)
        J_fm = _jacobian_at(by_forward_mode, offsets, parameters)
        for block in (slice(0, n), slice(n, None)):     # state derivatives, then outputs (other units)
            a, b = J_cs[block], J_fm[block]
            top = np.abs(b).max()
            assert top > 0
            rows = np.abs(b).max(axis=1)
            # A row below 1e-9 of its block is a quantity that is exactly zero -- the reaction moment about a
            # free pivot's axis -- computed as a difference of the block's terms: rounding in both, asserted so.
            # Elsewhere the two agree to 1e-13 of a row, but to 1.2e-10 and 2.6e-10 on the six-axis elbow's
            # reaction moment about its axis (8000 N m/rad against the block's 2.5e7: the same cancellation,
            # partial): 1e-9, while a wrong derivative is off by its own size.
            zero = rows < 1e-9 * top
            assert np.abs(a[zero]).max(initial=0.0) < 1e-9 * top
            err = (np.abs(a - b)[~zero] / rows[~zero, None]).max()
            print(f"{name}: largest difference {err:.2e} of its row's largest entry; {zero.sum()} rows at zero")
            assert err < 1e-9


def test_only_real_analytic_operations_take_the_complex_step():
    x = ca.SX.sym("x", 2)
    assert complex_step_applies(ca.Function("f", [x], [ca.sin(x[0]) * x[1] / ca.cos(x[0]) + x[1] ** 2]))
    for name, expr in [("fabs", ca.fabs(x[0])), ("if_else", ca.if_else(x[0] < 0, x[1], 2 * x[1])),
                       ("fmax", ca.fmax(x[0], x[1])), ("atan2", ca.atan2(x[0], x[1]))]:
        assert not complex_step_applies(ca.Function(name, [x], [expr])), name
    m = ca.MX.sym("m", 2)
    assert not complex_step_applies(ca.Function("graph", [m], [2 * m]))     # a matrix graph is not scalar code


def test_a_binary_without_complex_arithmetic_refuses_only_the_derivatives(example_fmu, tmp_path):
    """The FMU's sources compiled as by a C compiler without C99 complex arithmetic (MSVC's C compiler defines no
    complex types; ``__STDC_NO_COMPLEX__`` says so): it builds, steps as the shipped binary does, and answers
    fmi2GetDirectionalDerivative with fmi2Error and the reason."""
    import subprocess

    from fmpy import simulate_fmu
    from fmpy.fmi1 import FMICallException
    from fmpy.model_description import read_build_description

    from flexlink.run.host import FmuHost

    fmu = example_fmu("rotating_link")
    with zipfile.ZipFile(fmu) as z:
        z.extractall(tmp_path)
    files = read_build_description(fmu)[0].sourceFileSets[0].sourceFiles
    library = tmp_path / "binaries" / "linux64" / "rotating_link.so"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-shared", "-fPIC",
                    "-fvisibility=hidden", "-D__STDC_NO_COMPLEX__=1", f"-I{tmp_path / 'sources'}",
                    *(str(tmp_path / "sources" / f) for f in files), "-o", str(library), "-lm"], check=True)
    shipped = simulate_fmu(str(fmu), stop_time=0.2, output_interval=1e-3)
    rebuilt = simulate_fmu(str(tmp_path), stop_time=0.2, output_interval=1e-3)
    for name in shipped.dtype.names:
        np.testing.assert_array_equal(rebuilt[name], shipped[name])
    repacked = tmp_path / "no_complex.fmu"     # the FMU with the rebuilt binary, as an importer would get it
    with zipfile.ZipFile(repacked, "w") as z:
        for f in tmp_path.rglob("*"):
            if f.is_file() and f != repacked:
                z.write(f, f.relative_to(tmp_path).as_posix())
    with FmuHost(repacked) as host:            # its errors carry the FMU's logged message
        host.initialize()
        with pytest.raises(FMICallException) as refused:
            host.call("fmi2GetDirectionalDerivative", host.instance.getDirectionalDerivative,
                      [host.value_reference("arm.tip.v")], [host.value_reference("hub.tau")], [1.0])
    assert "compiled without C99 complex arithmetic" in str(refused.value)
