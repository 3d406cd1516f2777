"""The sampled MIMO LQG as a standalone FMI 2.0 Co-Simulation FMU in pure C (``flexlink control --export-fmu``).

The FMU is :class:`controllers.multijoint.MimoLQGLaw` — the Kalman current estimator and the discrete LQR
gains of a :class:`controllers.manoeuvre.ControlDesign`, the torque saturation — with its sample time as the
one communication step it accepts.  ``controllers/ctrl_fmu.c`` is the generic C; :func:`export_controller_fmu`
writes the design's numbers as ``ctrl_data.h`` (every double with 17 significant digits: the C computes
with the very matrices Python does), the model description, compiles and zips.

Inputs (value references in this order): the sensors by their plant names (absolute), ``x_ref[i]`` the
reference state and ``u_ff[j]`` the feedforward (deviations from the design's operating point), ``w[i]``
the reference's own step in the estimator's prediction (:class:`MimoLQGLaw`'s ``W``; zero along a plant
trajectory).  Outputs: the torques by their plant input names, absolute, saturated.  ``fmi2DoStep(t_k)``
takes the sample from the inputs set at t_k (the current estimator corrects with the measurement before the
torque) and holds the torque as the output until the next step: no output depends on an input set at the
same communication point, and the importer's order of stepping decides the delay (``ctrl_fmu.c``).  With
``reference`` the FMU also plays a manoeuvre's reference and feedforward itself (its reference inputs then
add to it): a plant and this controller alone make the closed loop (:mod:`controllers.ssp`).

With the tip accelerometer the law reads its sensors along the reference (the plant sampled along it A_k,
B_k and the time-varying Kalman gain M_k per sample, and the expected measurement: the model's sensor
outputs at the estimate, or with ``prediction="linear"`` their linearisation h(x_ref,k), C_k, D_k:
:class:`controllers.multijoint.MimoLQGLaw`); the FMU then plays its manoeuvre and carries those as tables
(:func:`_along_data`), each up to its last change, its last row held after it, and the model's sensor
function as C that CasADi generates (``ctrl_sensors.c``, :mod:`controllers.sensor_model`) beside the
generic ``ctrl_fmu.c``.  Such a controller has no reference inputs: its tables hold for its own reference.

:class:`FmuLaw` drives such an FMU as a law of :class:`controllers.cosim.FmuLoop`: the plant FMU and the
controller FMU stepped side by side by fmpy, the controller first.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import tempfile
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import escape

import numpy as np

from controllers.design import DesignError, torque_inputs

if TYPE_CHECKING:
    from controllers.integral import IntegralDesign, ScheduledIntegral
    from controllers.manoeuvre import ControlDesign
    from controllers.multijoint import MimoLQGLaw
    from controllers.schedule import Schedule
    from controllers.trajectory import Reference

__all__ = ["FmuLaw", "along_law", "export_controller_fmu", "reads_along", "reference_tables"]

C_SOURCE = Path(__file__).resolve().parent / "ctrl_fmu.c"


def _c_array(name: str, a: np.ndarray) -> str:
    a = np.atleast_1d(np.asarray(a, dtype=float))
    if a.ndim == 1:
        return f"static const double {name}[{len(a)}] = {{{', '.join(f'{v:.17g}' for v in a)}}};\n"
    rows = ",\n    ".join("{" + ", ".join(f"{v:.17g}" for v in r) + "}" for r in a)
    return f"static const double {name}[{a.shape[0]}][{a.shape[1]}] = {{\n    {rows}}};\n"


def _schedule_data(schedule: Schedule, duration: float, integral: ScheduledIntegral | None = None) -> str:
    """The design points of a gain schedule as C arrays.

    Of a ``controllers.schedule.Schedule``: the path parameters and (M, C, K_d, A_d, B_d), each flattened
    row-major; the manoeuvre time that maps t to the path parameter.  With ``integral`` (its
    :class:`controllers.integral.ScheduledIntegral`) K_d is each point's K_x and ``SKI`` holds its K_ξ.
    """
    from controllers.schedule import _matrices

    mats = [_matrices(d) for d in schedule.designs] if integral is None else integral.tables
    names = ("SMK", "SCY", "SKD", "SAD", "SBD") + (() if integral is None else ("SKI",))
    out = f"#define NSCHED {len(mats)}\n#define TMOVE {float(duration):.17g}\n" + _c_array("SSIG", schedule.sigma)
    for k, name in enumerate(names):
        out += _c_array(name, np.concatenate([np.asarray(m[k], dtype=float).ravel() for m in mats]))
    return out


def _data(d: ControlDesign, limits: np.ndarray, guid: str,
          tables: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None, delay: int = 0,
          integral: IntegralDesign | None = None) -> str:
    """The text of ``ctrl_data.h``: the design's numbers.

    ctrl_data.h: sizes, the estimator's and regulator's matrices, operating point, limits, sample time;
    with ``tables`` (x_ref, u_ff, w per sample) the built-in reference; the delay it compensates; with
    ``integral`` the augmented design's state gain as ``KD``, its integral gain ``KI`` and the encoders'
    rows ``IROW`` among the sensors (``INTEGRAL 1``).
    """
    p, kf = d.plant, d.kalman
    nx, ny, nu = p.sys.nstates, len(kf.sensors), len(d.lqr.inputs)
    y0 = p.y0[[p.output_row(s) for s in kf.sensors]]
    kd = d.lqr.Kd if integral is None else integral.Kx
    ref = "#define NREF 0\n"
    if tables is not None:
        x, u, w = tables
        ref = (f"#define NREF {len(x)}\n" + _c_array("REFX", np.reshape(x, (-1, nx)))
               + _c_array("REFU", np.reshape(u, (-1, nu))) + _c_array("REFW", np.reshape(w, (-1, nx))))
    return ("/* written by controllers/export.py: the design's numbers (17 significant digits) */\n"
            f'#define NX {nx}\n#define NY {ny}\n#define NU {nu}\n#define DT {d.dt:.17g}\n#define GUID "{guid}"\n'
            f"#define DELAY {int(delay)}\n"
            + _c_array("AD", d.lqr.plant_d.A) + _c_array("BD", np.asarray(d.lqr.plant_d.B).reshape(nx, nu))
            + _c_array("CY", kf.C) + _c_array("MK", kf.Md) + _c_array("KD", kd)
            + _c_array("Y0", y0) + _c_array("U0", p.u0[torque_inputs(p)]) + _c_array("LIM", limits) + ref
            + ("" if integral is None else _integral_data(integral)))


def _integral_data(integral: IntegralDesign) -> str:
    """``INTEGRAL 1``: the integral gain K_ξ and the rows of the integrated encoders (``ctrl_fmu.c``)."""
    rows = ", ".join(str(int(r)) for r in integral.rows)
    return ("#define INTEGRAL 1\n" + _c_array("KI", np.atleast_2d(integral.Ki))
            + f"static const int IROW[{len(integral.rows)}] = {{{rows}}};\n")


def _rows(a: np.ndarray) -> np.ndarray:
    """The rows of a per-sample table up to its last change (its last row then holds: ``ctrl_fmu.c``)."""
    flat = np.reshape(np.asarray(a, dtype=float), (len(a), -1))
    changed = np.flatnonzero(np.any(flat != flat[-1], axis=1))
    return flat[: changed[-1] + 2] if len(changed) else flat[:1]


def _along_data(law: MimoLQGLaw) -> str:
    """The law's model along the reference as C tables (sensors read along it: the tip accelerometer).

    Per sample k, of :class:`controllers.multijoint.MimoLQGLaw`: the expected measurement ``h(x_ref,k,
    u_ff,k−1)`` (``YREF``), its rows ``C_k``, ``D_k`` (``CKT``, ``DKT``), the feedforward held while it is sampled
    (``UFP``), the plant sampled along the reference ``A_k``, ``B_k`` (``AKT``, ``BKT``) — ``NALONG`` rows, the
    rest at the targets after them — and the time-varying Kalman gain ``M_k`` (``MKT``, ``NGAIN`` rows).  Empty
    when the law reads its sensors as at rest.  With the model's own sensor function (``law.h``, the default
    prediction) the expected measurement is computed by the generated ``ctrl_sensors.c`` instead of ``YREF``,
    ``CKT``, ``DKT`` and ``UFP``.
    """
    sc, al = law.schedule, law.along
    if sc is None or al is None:
        return "#define NALONG 0\n#define REF_INPUTS 1\n"
    tables = {"AKT": al.A, "BKT": al.B}
    if law.h is None:                  # the linear measurement model; else the generated sensor function
        tables.update({"YREF": sc.y_ref, "CKT": sc.C, "DKT": sc.D, "UFP": sc.u_ff_prev})
    n = max(len(_rows(a)) for a in tables.values())
    gain = _rows(al.M)
    out = f"#define NALONG {n}\n#define NGAIN {len(gain)}\n#define REF_INPUTS 0\n" + _c_array("MKT", gain)
    for name, a in tables.items():
        out += _c_array(name, np.reshape(np.asarray(a, dtype=float), (len(a), -1))[:n])
    return out


def along_law(d: ControlDesign, reference: Reference, limits: Sequence[float] | np.ndarray,
              schedule: Schedule | None = None, prediction: str = "model") -> MimoLQGLaw:
    """The Python law a controller FMU playing ``reference`` runs (:class:`MimoLQGLaw` or the scheduled one)."""
    from controllers.multijoint import MimoLQGLaw
    from controllers.schedule import ScheduledLQGLaw

    lim = [float(v) for v in np.asarray(limits, dtype=float)]
    if schedule is None:
        return MimoLQGLaw(d, lim, reference, prediction)
    return ScheduledLQGLaw(schedule, lim, reference, prediction)


def reference_tables(d: ControlDesign, reference: Reference, limits: Sequence[float] | np.ndarray,
                     schedule: Schedule | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The built-in reference of a controller FMU, one row per sample.

    Its last row, held after the end, is rest at the reference's final state (``w`` 0 there: the prediction
    is linearised about that rest, :func:`controllers.multijoint.reference_step`).

    Parameters
    ----------
    d : controllers.manoeuvre.ControlDesign
        The design.
    reference : controllers.trajectory.Reference
        The manoeuvre.
    limits : sequence of float
        Torque limits (the law's).
    schedule : controllers.schedule.Schedule, optional
        With a schedule ``w`` is the scheduled law's (the target design's step, as the C predicts with it).

    Returns
    -------
    tuple of arrays
        ``x_ref``, ``u_ff`` and the prediction's correction ``w`` of :class:`controllers.multijoint.MimoLQGLaw`
        (or :class:`controllers.schedule.ScheduledLQGLaw`); with sensors read along the reference, that of the
        plant sampled along it (:class:`controllers.multijoint.EstimatorAlong`).
    """
    law = along_law(d, reference, limits, schedule)
    W = law.W if law.along is None else law.along.W
    return reference.x.copy(), reference.u_ff.copy(), W.copy()


def frozen_radius_along(d: ControlDesign, law: MimoLQGLaw) -> tuple[float, int]:
    """The largest spectral radius of ``A_k − B_k K_d`` along the reference, and the sample where it is.

    ``A_k``, ``B_k``: the plant sampled along the reference (the accelerometer law's tables,
    :class:`controllers.multijoint.EstimatorAlong`); ``K_d`` the fixed design's gain.  Above 1, the fixed LQR
    is unstable about the poses there (a frozen-pose figure: the arm's motion is not in it).
    """
    assert law.along is not None
    rad = [float(np.max(np.abs(np.linalg.eigvals(A - B @ d.lqr.Kd)))) for A, B in zip(law.along.A, law.along.B,
                                                                                          strict=True)]
    k = int(np.argmax(rad))
    return rad[k], k


def check_delayed_along(d: ControlDesign, law: MimoLQGLaw, reference: Reference) -> None:
    """Refuse the fixed accelerometer LQG for a loop one sample late where its LQR is unstable along the path.

    Why (docs/control.md, "the fixed accelerometer LQG and the sample of delay"): the accelerometer's estimator
    follows the state along the reference, so the delayed predictive loop behaves as the state feedback
    ``A_k − B_k K_d`` there; where its spectral radius exceeds 1 (the two-link example's straight arm: 1.187)
    the loop's alternating mode grows at that rate (measured 1.18 per sample) and the estimate diverges.
    Undelayed, the same loop passes in the FMU (SS22's damping of the fast modes; with cvodes it diverges).
    """
    radius, k = frozen_radius_along(d, law)
    if radius <= 1.0:
        return
    p = d.plant
    rows = [p.states.index(f"{j}.theta") for j in d.actuated_joints]
    angles = np.degrees(p.x0[rows] + np.asarray(reference.x[k])[rows])
    pose = ", ".join(f"{j} {a:.3g}" for j, a in zip(d.actuated_joints, angles, strict=True))
    raise DesignError(f"the fixed LQR is unstable along this path (spectral radius of the plant sampled along the "
                      f"reference with its gain {radius:.4g} at t = {k * d.dt:.4g} s, {pose} deg), and with the SSP "
                      "package's sample of delay the accelerometer LQG diverges there: schedule it (--schedule N) or "
                      "use the strain gauges")


def reads_along(d: ControlDesign) -> bool:
    """Whether the design's sensors are read along a reference: any but encoders and root strain gauges.

    Encoders and root strain gauges are linear in the state (``y₀ + C x`` is exact); the tip accelerometer is
    not (:func:`controllers.laws.measurement_schedule`), and its controller FMU carries the law's model along
    the manoeuvre as tables (:func:`export_controller_fmu`).
    """
    return bool(np.any(d.kalman.D != 0)) or any(not s.endswith((".theta", ".root.moment")) for s in d.kalman.sensors)


def _variables(d: ControlDesign, reference_inputs: bool = True) -> list[tuple[str, str, str, str]]:
    """(name, causality, description, start) of every variable, in value-reference order.

    ``reference_inputs=False``: no ``x_ref``, ``u_ff``, ``w`` inputs (a controller that reads its sensors along
    its built-in reference: its tables and measurement model hold for that reference only).
    """
    p, kf = d.plant, d.kalman
    y0 = p.y0[[p.output_row(s) for s in kf.sensors]]
    out = [(s, "input", f"sensor {s} (absolute)", f"{v:.17g}") for s, v in zip(kf.sensors, y0, strict=True)]
    if reference_inputs:
        out += [(f"x_ref[{i}]", "input", f"reference of {s} (deviation from the operating point)", "0")
                for i, s in enumerate(p.states)]
        out += [(f"u_ff[{j}]", "input", f"feedforward {u} (deviation)", "0") for j, u in enumerate(d.lqr.inputs)]
        out += [(f"w[{i}]", "input", f"reference's step in the prediction of {s} (0 along a plant trajectory)", "0")
                for i, s in enumerate(p.states)]
    out += [(u, "output", f"torque {u} (absolute, saturated)", "") for u in d.lqr.inputs]
    return out


def _model_description(d: ControlDesign, ident: str, guid: str, sources: Sequence[str] = ("ctrl_fmu.c",),
                       reference_inputs: bool = True) -> str:
    vs = _variables(d, reference_inputs)
    nu = len(d.lqr.inputs)
    files = "".join(f'<File name="{escape(f)}"/>' for f in sources)
    lines = []
    for vr, (name, caus, desc, start) in enumerate(vs):
        if caus == "input":
            lines.append(f'    <ScalarVariable name="{escape(name)}" valueReference="{vr}" causality="input" '
                         f'variability="discrete" description="{escape(desc)}"><Real start="{start}"/>'
                         "</ScalarVariable>")
        else:
            lines.append(f'    <ScalarVariable name="{escape(name)}" valueReference="{vr}" causality="output" '
                         f'variability="discrete" initial="calculated" description="{escape(desc)}"><Real/>'
                         "</ScalarVariable>")
    first = len(vs) - nu + 1             # the torque of the last sample taken: no input of the same instant
    unknowns = "\n".join(f'      <Unknown index="{first + j}" dependencies=""/>' for j in range(nu))
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{escape(ident)}" guid="{guid}"
  generationTool="flexlink control --export-fmu"
  description="sampled MIMO LQG (Kalman current estimator + discrete LQR) of {escape(d.plant.model.scene.name)}"
  variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{escape(ident)}" canHandleVariableCommunicationStepSize="false"
    canInterpolateInputs="false" canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="false"
    canGetAndSetFMUstate="false" canSerializeFMUstate="false" providesDirectionalDerivative="false">
    <SourceFiles>{files}</SourceFiles>
  </CoSimulation>
  <DefaultExperiment startTime="0" stepSize="{d.dt:.17g}"/>
  <ModelVariables>
{chr(10).join(lines)}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{unknowns}
    </Outputs>
    <InitialUnknowns>
{unknowns}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def _check_integral(d, integral, schedule, scheduled) -> None:
    """Refuse an integral design that is not this design's (or its schedule's), or that the C cannot run."""
    if integral is None:
        return
    if reads_along(d):
        raise DesignError("integral action in the controller FMU: with the encoders and strain gauges only")
    if scheduled is None and (integral.design is not d or schedule is not None):
        raise DesignError("integral action in the controller FMU: the integral design of this design (with a "
                          "schedule: its design_scheduled_integral)")
    if scheduled is not None and scheduled.schedule is not schedule:
        raise DesignError("scheduled integral action in the controller FMU: the schedule's own integral design")


def export_controller_fmu(d: ControlDesign, path: str | os.PathLike[str], limits: Sequence[float] | None = None,
                          identifier: str | None = None, reference: Reference | None = None, delay: int = 0,
                          schedule: Schedule | None = None, duration: float | None = None,
                          prediction: str = "model",
                          integral: IntegralDesign | ScheduledIntegral | None = None) -> Path:
    """Write the design's sampled LQG (:class:`controllers.multijoint.MimoLQGLaw`) as an FMI 2.0 CS FMU.

    ``limits``: the torque saturation per actuated joint (default: the design's torque limits).  The sensors
    are those of the multi-joint run.  ``reference`` (a :class:`controllers.trajectory.Reference` at the design's
    sample time): built in (:func:`reference_tables`); it is required with the tip accelerometer, whose
    measurement model, sampled plant and Kalman gains along it become tables of the C (:func:`_along_data`).
    ``delay=1``: for an importer that applies the output one sample later
    (Jacobi; :class:`controllers.ssp.PredictiveLQGLaw`).  ``schedule`` (a
    :class:`controllers.schedule.Schedule` whose first design is ``d``) with the manoeuvre's ``duration``:
    the matrices of :class:`controllers.schedule.ScheduledLQGLaw`, switched along the path in the C.
    ``prediction``: how the accelerometer's law predicts its measurements (:class:`MimoLQGLaw`): ``"model"``,
    the model's sensor outputs at the estimate, generated as C by CasADi (``ctrl_sensors.c``:
    :mod:`controllers.sensor_model`), or ``"linear"``, their linearisation along the reference as tables.
    ``integral`` (:func:`controllers.integral.design_integral` of ``d``): the LQG with integral action on the
    joint positions and its anti-windup (:class:`controllers.integral.IntegralLQGLaw`; with ``delay=1``
    :class:`controllers.ssp.PredictiveIntegralLQGLaw`); with a schedule its
    :class:`controllers.integral.ScheduledIntegral` (:class:`controllers.integral.ScheduledIntegralLQGLaw`;
    with ``delay=1`` :class:`controllers.ssp.ScheduledPredictiveIntegralLQGLaw`); not with sensors read along
    the reference.
    """
    from flexlink.export.cbuild import compile_shared_library, fmi_headers_dir

    if reads_along(d):
        from controllers.multijoint import check_multijoint

        check_multijoint(d)                 # the sensors the multi-joint law reads, one message for the others
        if reference is None:
            raise DesignError(f"--export-fmu: the controller FMU reads {', '.join(d.kalman.sensors)} along the "
                              "manoeuvre's reference (the accelerometer), so it plays the manoeuvre itself: give "
                              "--target and --duration")
    path = Path(path)
    if path.suffix != ".fmu":
        raise DesignError(f"--export-fmu {path}: expected a file name ending in .fmu")
    lim = np.asarray([d.lqr.torque_limits[j] for j in d.actuated_joints] if limits is None else limits, dtype=float)
    ident = identifier or "".join(c if c.isalnum() else "_" for c in f"{d.plant.model.scene.name}_lqg")
    if schedule is not None and (schedule.designs[0] is not d or not (duration is not None and duration > 0)):
        raise DesignError("a scheduled controller FMU needs the schedule of this design and the manoeuvre time")
    if delay not in (0, 1):
        raise DesignError(f"delay: 0 or 1 sample, got {delay}")
    from controllers.integral import IntegralDesign, ScheduledIntegral

    scheduled_integral = integral if isinstance(integral, ScheduledIntegral) else None
    _check_integral(d, integral, schedule, scheduled_integral)
    start_integral = integral if isinstance(integral, IntegralDesign) else (
        None if scheduled_integral is None else scheduled_integral.designs[0])
    tables, along, law = None, "#define NALONG 0\n#define REF_INPUTS 1\n", None
    if reference is not None:
        if abs(reference.dt - d.dt) > 1e-12 * d.dt:
            raise DesignError(f"the reference samples at {reference.dt} s, the controller at {d.dt} s")
        law = along_law(d, reference, lim, schedule, prediction)
        if delay == 1 and schedule is None and law.along is not None:
            check_delayed_along(d, law, reference)
        tables = (reference.x, reference.u_ff, law.W if law.along is None else law.along.W)
        along = _along_data(law)
    data = _data(d, lim, "{GUID}", tables, delay, start_integral) + along
    if schedule is not None and duration is not None:
        data += _schedule_data(schedule, duration, scheduled_integral)
    with tempfile.TemporaryDirectory(prefix="flexlink-ctrl-") as tmp:
        root = Path(tmp)
        src = root / "sources"
        src.mkdir()
        sources = [src / "ctrl_fmu.c"]
        if law is not None and law.h is not None:
            from controllers.sensor_model import write_sensor_source

            gen = write_sensor_source(law.h, src, d.plant.model.scene.name, law.sensors)
            data += gen.defines() + _c_array("X0", d.plant.x0)
            sources.append(gen.source)
        guid = hashlib.sha256("".join([data, *(f.read_text() for f in sources[1:])]).encode()).hexdigest()[:32]
        guid = f"{{{guid[:8]}-{guid[8:12]}-{guid[12:16]}-{guid[16:20]}-{guid[20:32]}}}"
        shutil.copy(C_SOURCE, src / "ctrl_fmu.c")
        (src / "ctrl_data.h").write_text(data.replace('"{GUID}"', f'"{guid}"', 1))
        (root / "modelDescription.xml").write_text(_model_description(d, ident, guid, [f.name for f in sources],
                                                                      "REF_INPUTS 1" in data))
        compile_shared_library(sources, [src, fmi_headers_dir()], root / "binaries" / "linux64" / f"{ident}.so")
        path.parent.mkdir(parents=True, exist_ok=True)
        try:
            with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
                for f in sorted(root.rglob("*")):
                    if f.is_file():
                        z.write(f, f.relative_to(root).as_posix())
        except OSError as e:
            raise DesignError(f"--export-fmu {path}: cannot write the file ({e.strerror})") from None
    return path


class FmuLaw:
    """A controller FMU stepped as a sampled law.

    A controller FMU written by :func:`export_controller_fmu`, stepped as a law of
    :class:`controllers.cosim.FmuLoop`: at sample k set (y_k, x_ref,k, u_ff,k, w_k), ``fmi2DoStep(t_k, dt)``,
    read the torques (the plant steps after it with them).  ``W`` is the law's reference correction
    (:class:`MimoLQGLaw`'s ``W``); ``builtin=True``: the FMU plays its own reference, the reference inputs
    stay 0.
    """

    kind = "lqr-fmu"

    def __init__(self, fmu: str | os.PathLike[str], W: np.ndarray | None = None, builtin: bool = False):
        from flexlink.run.host import FmuHost

        self.host = FmuHost(fmu, interface="CoSimulation", instance_name="controller")
        self.md = self.host.model_description
        self.dt = float(self.md.defaultExperiment.stepSize)
        vs = self.md.modelVariables
        names = [v.name for v in vs if v.causality == "input"]
        self.inputs = [v.name for v in vs if v.causality == "output"]
        n_in, nx = len(names), sum(n.startswith("x_ref[") for n in names)
        # without reference inputs (a controller reading its sensors along its own reference) all are sensors
        self.sensors = names[: n_in - 2 * nx - len(self.inputs)] if nx else names
        self.builtin = builtin
        if W is None and not builtin:
            self.host.close()
            raise DesignError("FmuLaw: the reference's correction W is needed unless the FMU plays its own reference")
        self.W = np.zeros((1, nx)) if W is None else np.asarray(W, dtype=float)
        self.vr_in = (ctypes.c_uint * n_in)(*range(n_in))
        self.val_in = (ctypes.c_double * n_in)()
        self.in_ = np.ctypeslib.as_array(self.val_in)
        m = len(self.inputs)
        self.vr_out = (ctypes.c_uint * m)(*range(n_in, n_in + m))
        self.val_out = (ctypes.c_double * m)()
        self.k = 0

    @property
    def slave(self) -> Any:
        """The fmpy ``FMU2Slave`` of the host."""
        return self.host.instance

    def reset(self) -> None:
        """Reset (after a first run) and initialise the controller FMU: sample 0 next."""
        self.host.initialize()
        self.k = 0

    def step(self, y: np.ndarray, x_ref: np.ndarray, u_ff: np.ndarray) -> np.ndarray:
        """Set sample k's inputs, step the controller FMU over one sample, return its torques."""
        from fmpy.fmi1 import FMICallException

        ny, nx = len(self.sensors), len(x_ref)
        self.in_[:ny] = y
        if not self.builtin and len(self.in_) > ny:
            self.in_[ny:ny + nx] = x_ref
            self.in_[ny + nx:ny + nx + len(self.inputs)] = u_ff
            self.in_[ny + nx + len(self.inputs):] = self.W[self.k]
        s = self.slave
        try:
            s.fmi2SetReal(s.component, self.vr_in, len(self.in_), self.val_in)
            s.fmi2DoStep(s.component, self.k * self.dt, self.dt, 1)
            s.fmi2GetReal(s.component, self.vr_out, len(self.inputs), self.val_out)
        except FMICallException as e:
            raise self.host.refusal(e.function, e.status, where=f"controller sample {self.k}") from None
        self.k += 1
        return np.ctypeslib.as_array(self.val_out).copy()

    def close(self) -> None:
        """Terminate and free the controller FMU (once) and delete its extracted files."""
        self.host.close()
