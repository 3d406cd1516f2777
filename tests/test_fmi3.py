"""``flexlink build --fmi 3``: the FMI 3.0 FMU of a scene against the FMI 2.0 FMU of the same scene (issue 17).

The references are fmpy's FMI 3.0 validation (schema and rules), fmpy's simulation of the FMI 2 FMU in the same
interface with the same settings, the FMI 2 FMU's directional derivatives, and the FMI 3.0 rules for the calls
(an Int32 set with fmi3SetInt32, the adjoint the transpose of the directional derivative)."""

from __future__ import annotations

import json
import shutil
import subprocess
import zipfile
from xml.etree import ElementTree

import fmpy
import numpy as np
import pytest
from conftest import EXAMPLES
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Model, FMU3Slave
from fmpy.validation import validate_fmu

from flexlink.export.cbuild import MINGW_CC, fmi_headers_dir
from flexlink.export.fmu import build_fmu

# steel_beam_raise: finite elements and built-in kinematic laws.  Its stiff elements defeat fmpy's explicit Euler
# and CVode's default step limit, so Model Exchange is compared on rotating_link only.
SCENES = ("rotating_link", "steel_beam_raise")


@pytest.fixture(scope="module")
def fmi3_fmu(tmp_path_factory):
    """``fmi3_fmu(name)``: the FMI 3 FMU of examples/<name>.toml, built once per module."""
    built = {}

    def get(name):
        if name not in built:
            built[name] = build_fmu(EXAMPLES / f"{name}.toml", tmp_path_factory.mktemp("fmi3") / f"{name}.fmu",
                                    fmi_version=3).fmu
        return built[name]
    return get


def torque(md, stop):
    """A smooth input on every input of the scene (none for a scene driven by its laws)."""
    names = [v.name for v in md.modelVariables if v.causality == "input"]
    if not names:
        return None
    t = np.linspace(0.0, stop, 201)
    return np.array([(ti, *(0.2 * np.sin(2 * np.pi * ti / stop) for _ in names)) for ti in t],
                    dtype=[("time", float), *((n, float) for n in names)])


def equal_runs(a, b, tolerance=1e-12):
    """The largest difference of any recorded variable, against the largest magnitude of the run."""
    assert a.dtype.names == b.dtype.names and len(a) == len(b)
    peak = max(float(np.max(np.abs(b[n]))) for n in b.dtype.names)
    worst = max(float(np.max(np.abs(a[n] - b[n]))) for n in b.dtype.names)
    assert worst <= tolerance * peak, (worst, peak)


@pytest.mark.parametrize("name", SCENES)
def test_fmi3_model_description_is_valid_and_matches_fmi2(fmi3_fmu, example_fmu, name):
    fmu3 = fmi3_fmu(name)
    assert validate_fmu(str(fmu3)) == []
    md3 = fmpy.read_model_description(str(fmu3))
    md2 = fmpy.read_model_description(str(example_fmu(name)))
    assert md3.fmiVersion == "3.0" and md3.instantiationToken == md2.guid
    assert md3.coSimulation is not None and md3.modelExchange is not None
    with zipfile.ZipFile(fmu3) as z:
        assert f"binaries/x86_64-linux/{md3.coSimulation.modelIdentifier}.so" in z.namelist()
        root = ElementTree.fromstring(z.read("modelDescription.xml"))
    for interface in ("ModelExchange", "CoSimulation"):     # fmpy 0.3.32 does not read these FMI 3 flags
        flags = root.find(interface).attrib
        for flag in ("canGetAndSetFMUState", "canSerializeFMUState", "providesDirectionalDerivatives",
                     "providesAdjointDerivatives"):
            assert flags[flag] == "true", (interface, flag)
    # the same variables, value references, units, display units and ranges; Real is Float64, Integer Int32
    v3 = {v.name: v for v in md3.modelVariables}
    for v in md2.modelVariables:
        w = v3[v.name]
        assert w.type == {"Real": "Float64", "Integer": "Int32"}[v.type], v.name
        assert (w.valueReference, w.causality, w.variability, w.unit, w.displayUnit) == \
               (v.valueReference, v.causality, v.variability, v.unit, v.displayUnit), v.name
        for attr in ("start", "min", "max"):
            assert (None if getattr(w, attr) is None else float(getattr(w, attr))) == \
                   (None if getattr(v, attr) is None else float(getattr(v, attr))), (v.name, attr)
    assert v3["time"].causality == "independent"
    # the model structure: the same outputs, derivatives and initial unknowns with the same dependencies
    for s2, s3 in ((md2.outputs, md3.outputs), (md2.derivatives, md3.derivatives),
                   (md2.initialUnknowns, md3.initialUnknowns)):
        assert [(u.variable.name, sorted(d.name for d in u.dependencies)) for u in s2] == \
               [(u.variable.name, sorted(d.name for d in u.dependencies)) for u in s3]


@pytest.mark.parametrize("name, stop, settings", [
    ("rotating_link", 0.5, {"fmi_type": "CoSimulation"}),
    ("rotating_link", 0.5, {"fmi_type": "ModelExchange", "solver": "CVode", "relative_tolerance": 1e-9}),
    ("rotating_link", 0.1, {"fmi_type": "ModelExchange", "solver": "Euler", "step_size": 1e-5}),
    ("steel_beam_raise", 0.3, {"fmi_type": "CoSimulation"}),
], ids=["cs-rotating_link", "me-cvode-rotating_link", "me-euler-rotating_link", "cs-steel_beam_raise"])
def test_fmi3_simulates_as_the_fmi2_fmu(fmi3_fmu, example_fmu, name, stop, settings):
    fmu2 = str(example_fmu(name))
    u = torque(fmpy.read_model_description(fmu2), stop)
    runs = [fmpy.simulate_fmu(str(f), stop_time=stop, output_interval=0.01, input=u, **settings)
            for f in (fmi3_fmu(name), fmu2)]
    assert len(runs[0]) == round(stop / 0.01) + 1
    assert max(float(np.max(np.abs(runs[1][n]))) for n in runs[1].dtype.names if n != "time") > 0  # it moves
    equal_runs(*runs)


def slave(fmu, cls=FMU3Slave):
    md = fmpy.read_model_description(str(fmu))
    kind = md.coSimulation if cls is FMU3Slave else md.modelExchange
    inst = cls(guid=md.instantiationToken, unzipDirectory=fmpy.extract(str(fmu)),
               modelIdentifier=kind.modelIdentifier, instanceName="fmi3")
    inst.instantiate()
    return md, inst, {v.name: v.valueReference for v in md.modelVariables}


def test_fmi3_fmu_state_round_trip(fmi3_fmu):
    md, s, vr = slave(fmi3_fmu("rotating_link"))
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    try:
        s.setInt32([vr["solver.order"]], [4])
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()

        def run(t0, n):
            rows = []
            for k in range(n):
                s.setFloat64([vr["hub.tau"]], [0.3 * (k % 3)])
                s.doStep(t0 + 0.01 * k, 0.01)
                rows.append(s.getFloat64(outputs + [vr["time"]]))
            return np.array(rows)

        run(0.0, 5)
        state = s.getFMUState()
        blob = s.serializeFMUState(state)
        first = run(0.05, 10)
        s.setFMUState(state)
        assert np.array_equal(run(0.05, 10), first)
        restored = s.deserializeFMUState(blob)
        s.setFMUState(restored)
        assert np.array_equal(run(0.05, 10), first)
        assert first[-1, -1] == pytest.approx(0.15, abs=1e-12)     # time, the independent variable
        s.freeFMUState(state)
        s.freeFMUState(restored)
    finally:
        s.freeInstance()


def test_fmi3_derivatives_equal_fmi2_and_adjoint_is_the_transpose(fmi3_fmu, example_fmu):
    from fmpy.fmi2 import FMU2Model

    md3, m3, vr = slave(fmi3_fmu("rotating_link"), FMU3Model)
    md2 = fmpy.read_model_description(str(example_fmu("rotating_link")))
    m2 = FMU2Model(guid=md2.guid, unzipDirectory=fmpy.extract(str(example_fmu("rotating_link"))),
                   modelIdentifier=md2.modelExchange.modelIdentifier, instanceName="fmi2")
    m2.instantiate()
    try:
        unknowns = [u.variable.valueReference for u in md3.derivatives] + \
                   [u.variable.valueReference for u in md3.outputs]
        knowns = [u.variable.derivative.valueReference for u in md3.derivatives] + [vr["hub.tau"]]
        x = np.array([0.3, 0.01, -0.02, 0.005, 1.0, 0.1, 0.2, -0.1])
        m2.setReal([vr["hub.tau"]], [0.4])
        m2.setupExperiment(startTime=0.0)
        m2.enterInitializationMode()
        m2.exitInitializationMode()
        m2.newDiscreteStates()
        m2.enterContinuousTimeMode()
        m2.setContinuousStates(x.ctypes.data_as(fmpy.fmi2.POINTER(fmpy.fmi2.c_double)), len(x))
        m3.setFloat64([vr["hub.tau"]], [0.4])
        m3.enterInitializationMode(startTime=0.0)
        m3.exitInitializationMode()
        m3.updateDiscreteStates()
        m3.enterContinuousTimeMode()
        m3.setContinuousStates(x.ctypes.data_as(fmpy.fmi2.POINTER(fmpy.fmi2.c_double)), len(x))
        J = np.array([m3.getDirectionalDerivative(unknowns, [k], [1.0]) for k in knowns]).T
        J2 = np.array([m2.getDirectionalDerivative(unknowns, [k], [1.0]) for k in knowns]).T
        assert np.array_equal(J, J2) and np.any(J != 0)
        seed = np.linspace(-1.0, 1.0, len(unknowns))
        adjoint = np.array(m3.getAdjointDerivative(unknowns, knowns, list(seed), nSensitivity=len(knowns)))
        np.testing.assert_allclose(adjoint, J.T @ seed, rtol=1e-14, atol=1e-14 * np.abs(J).max())
    finally:
        m3.freeInstance()
        m2.freeInstance()


def test_fmi3_refuses_bad_calls(fmi3_fmu):
    """Bad input is fmi3Error with the reason, never a crash; the instance is revived by fmi3Reset."""
    md, s, vr = slave(fmi3_fmu("rotating_link"))
    statuses = []
    try:
        for call in (lambda: s.setInt32([vr["solver.order"]], [3]),
                     lambda: s.setFloat64([vr["solver.order"]], [2.5]),
                     lambda: s.setFloat64([vr["time"]], [1.0]),
                     lambda: s.setFloat64([10_000], [1.0]),
                     lambda: s.setBoolean([vr["solver.order"]], [True]),
                     lambda: s.doStep(0.0, 0.01),                       # before initialization
                     lambda: s.enterEventMode()):                      # a Model Exchange function
            with pytest.raises(FMICallException) as e:
                call()
            statuses.append(int(e.value.status))
            s.reset()
        assert statuses == [3] * 7                                  # fmi3Error
        s.enterInitializationMode(startTime=0.0)
        s.exitInitializationMode()
        s.doStep(0.0, 0.01)
    finally:
        s.freeInstance()


@pytest.mark.skipif(shutil.which(MINGW_CC) is None, reason=f"{MINGW_CC} is not installed")
def test_fmi3_win64_binary_exports_the_fmi3_interface(tmp_path):
    rep = build_fmu(EXAMPLES / "rotating_link.toml", tmp_path / "rl.fmu", fmi_version=3,
                    platforms="linux64,win64")
    assert validate_fmu(str(rep.fmu)) == []
    dll = "binaries/x86_64-windows/rotating_link.dll"
    with zipfile.ZipFile(rep.fmu) as z:
        z.extract(dll, tmp_path)
    dumped = subprocess.run(["x86_64-w64-mingw32-objdump", "-p", str(tmp_path / dll)], capture_output=True,
                            text=True, check=True).stdout
    exported = {w for w in dumped.split() if w.startswith("fmi")}
    # every function the FMI 3.0 header declares (its FMI3_Export lines), and nothing else
    header = fmi_headers_dir() / "fmi3Functions.h"
    declared = {line.split()[2].rstrip(";") for line in header.read_text().splitlines()
                if line.startswith("FMI3_Export")}
    assert exported == declared


def test_flexlink_check_runs_on_an_fmi3_fmu(fmi3_fmu, tmp_path, capsys):
    """``flexlink check`` on an FMI 3 FMU: fmpy's validation with every variable read back through the binary,
    both interfaces simulated and compared, legal random call sequences, FMU state and directional derivatives
    (through fmpy's FMI 3 API); the FMI 2-only checks are reported as skipped.  A value reference that the binary
    does not know is caught."""
    from flexlink.cli import main

    fmu = fmi3_fmu("rotating_link")
    assert main(["check", str(fmu), "--me-vs-cs-stop", "0.05", "--fuzz", "20", "--json"]) == 0
    results = {r["name"]: r["status"] for r in json.loads(capsys.readouterr().out)["checks"]}
    assert {name for name, status in results.items() if status == "pass"} >= \
           {"model-description", "me-vs-cs", "fuzz", "fmu-state", "directional-derivatives", "illegal-calls"}
    assert "libcosim" in {name for name, status in results.items() if status == "skip"}       # FMI 2.0 only
    bad = tmp_path / "bad.fmu"
    with zipfile.ZipFile(fmu) as z, zipfile.ZipFile(bad, "w") as out:
        for item in z.infolist():
            data = z.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'name="solver.tolerance" valueReference="8"',
                                    b'name="solver.tolerance" valueReference="9999"')
                assert b'valueReference="9999"' in data
            out.writestr(item, data)
    assert main(["check", str(bad), "--only", "model-description"]) == 1
    assert "9999" in capsys.readouterr().out


@pytest.mark.parametrize("cc", ["gcc", MINGW_CC])
def test_fmi3_sources_compile_clean_as_strict_c99(fmi3_fmu, tmp_path, cc):
    """The FMI 3 FMU's ``sources/``: every file its buildDescription.xml lists (all the C files shipped, with
    fmi3Functions.c instead of fmi2Functions.c), strict C99 with every warning an error."""
    from fmpy.model_description import read_build_description

    if shutil.which(cc) is None:
        pytest.skip(f"{cc} is not installed")
    fmu = fmi3_fmu("rotating_link")
    with zipfile.ZipFile(fmu) as z:
        z.extractall(tmp_path)
    files = read_build_description(fmu, validate=True)[0].sourceFileSets[0].sourceFiles
    assert sorted(files) == sorted(p.name for p in (tmp_path / "sources").glob("*.c"))
    assert "fmi3Functions.c" in files and "fmi2Functions.c" not in files
    flags = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O1", "-shared"] + (["-fPIC"] if cc == "gcc"
                                                                                          else [])
    res = subprocess.run([cc, *flags, f"-I{tmp_path / 'sources'}", *(str(tmp_path / "sources" / f) for f in files),
                          "-o", str(tmp_path / "lib"), "-lm"], capture_output=True, text=True, check=False)
    assert res.returncode == 0 and res.stderr == "", res.stderr[-4000:]
