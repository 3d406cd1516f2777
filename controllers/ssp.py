"""The plant FMU and the controller FMU as one SSP 1.0 package (``flexlink control --export-ssp``).

``SystemStructure.ssd`` names two components, ``resources/plant.fmu`` (the scene's FMU) and
``resources/controller.fmu`` (:func:`controllers.export.export_controller_fmu`, with the manoeuvre's
reference and feedforward built in), and connects the plant's sensors to the controller's inputs of the same
names and the controller's torques to the plant's torque inputs.  The default experiment runs from 0 to the
end of the manoeuvre and its settling window; its communication step is the controller's sample time,
given where SSP 1.0 has no field for it: the Open Simulation Platform's annotation
(``osp:FixedStepAlgorithm baseStepSize``), which libcosim reads.  :func:`write_ssp` checks the ``.ssd``
against the normative SSP 1.0 schema that fmpy ships (``fmpy.ssp.ssd.read_ssd(validate=True)``).

**Co-simulation semantics.**  The controller FMU takes its sample in ``fmi2DoStep(t_k)`` from the inputs set
at t_k and holds the torque as its output from then on (``controllers/ctrl_fmu.c``).  An importer that steps
the controller first and the plant after it with the new torque (Gauss–Seidel, as :class:`controllers.export.
FmuLaw` in :class:`controllers.cosim.FmuLoop`) applies u_k over [t_k, t_k+1], the timing of the Python law.
libcosim's fixed-step algorithm steps all components in parallel and then exchanges their outputs
(Jacobi): the plant steps over [t_k, t_k+1] with the torque the controller output at t_k, the sample it took
at t_k−1, and over the first step with the controller's initial output.  That is the law delayed by one
sample (:class:`JacobiDelay`).  The LQG as designed does not survive that delay (on the two-link example
both libcosim and the delayed Python law leave the beam model's validity at t = 0.919 s, chattering between
the torque limits): the package's controller is therefore built for it (``DELAY 1``,
:class:`PredictiveLQGLaw`): it predicts the estimate one sample ahead with the torque being applied and
outputs the next sample's torque.  The like-for-like comparison of the SSP run in libcosim is
``JacobiDelay(PredictiveLQGLaw)`` in :class:`controllers.cosim.FmuLoop`.  A sensor with feedthrough (the tip
accelerometer) also sees the torque libcosim connects to the plant while it initialises: that loop is then
:class:`JacobiLoop`.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import zipfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import quoteattr

import numpy as np

from controllers.cosim import FmuLoop, LoopResult
from controllers.design import DesignError
from controllers.multijoint import MimoLQGLaw, checked_step

if TYPE_CHECKING:
    from controllers.integral import IntegralDesign, ScheduledIntegral
    from controllers.manoeuvre import ControlDesign
    from controllers.schedule import Schedule
    from controllers.trajectory import Reference

__all__ = ["JacobiDelay", "JacobiLoop", "PredictiveIntegralLQGLaw", "PredictiveLQGLaw",
           "ScheduledPredictiveIntegralLQGLaw", "ScheduledPredictiveLQGLaw", "write_ssp"]

PLANT, CONTROLLER = "plant", "controller"


def _connector(name: str, kind: str) -> str:
    """One ``ssd:Connector`` of a Real."""
    return f'          <ssd:Connector name={quoteattr(name)} kind="{kind}"><ssc:Real/></ssd:Connector>'


def system_structure(name: str, sensors: list[str], torques: list[str], dt: float, stop_time: float) -> str:
    """The ``SystemStructure.ssd`` text: the two components, their connections, the default experiment."""
    plant = [_connector(s, "output") for s in sensors] + [_connector(u, "input") for u in torques]
    ctrl = [_connector(s, "input") for s in sensors] + [_connector(u, "output") for u in torques]
    conns = [(PLANT, s, CONTROLLER, s) for s in sensors] + [(CONTROLLER, u, PLANT, u) for u in torques]
    lines = "\n".join(f"      <ssd:Connection startElement=\"{a}\" startConnector={quoteattr(b)} endElement=\"{c}\" "
                      f"endConnector={quoteattr(d)}/>" for a, b, c, d in conns)

    def component(el: str, connectors: list[str]) -> str:
        return (f'      <ssd:Component name="{el}" type="application/x-fmu-sharedlibrary" '
                f'source="resources/{el}.fmu">\n        <ssd:Connectors>\n' + "\n".join(connectors)
                + "\n        </ssd:Connectors>\n      </ssd:Component>")

    return f"""<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
  xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
  xmlns:osp="http://opensimulationplatform.com/SSP/OSPAnnotations"
  name={quoteattr(name)} version="1.0" generationTool="flexlink control --export-ssp">
  <ssd:System name={quoteattr(name)} description="the scene's FMU in closed loop with its sampled LQG">
    <ssd:Elements>
{component(PLANT, plant)}
{component(CONTROLLER, ctrl)}
    </ssd:Elements>
    <ssd:Connections>
{lines}
    </ssd:Connections>
  </ssd:System>
  <ssd:DefaultExperiment startTime="0" stopTime="{stop_time:.17g}">
    <ssd:Annotations>
      <ssc:Annotation type="com.opensimulationplatform">
        <osp:Algorithm><osp:FixedStepAlgorithm baseStepSize="{dt:.17g}"/></osp:Algorithm>
      </ssc:Annotation>
    </ssd:Annotations>
  </ssd:DefaultExperiment>
</ssd:SystemStructureDescription>
"""


def write_ssp(d: ControlDesign, plant_fmu: str | os.PathLike[str], path: str | os.PathLike[str],
              reference: Reference, limits: Sequence[float] | None = None, schedule: Schedule | None = None,
              integral: IntegralDesign | ScheduledIntegral | None = None) -> Path:
    """Write the SSP package of the plant FMU and the design's controller FMU playing ``reference``.

    The package is validated against the SSP 1.0 schema before it is written, so that a package on disk is
    one the standard's importers read.

    Parameters
    ----------
    d : controllers.manoeuvre.ControlDesign
        The design whose sampled LQG the controller FMU runs (predictive, ``DELAY 1``: module docstring).
    plant_fmu : path
        The scene's FMU.
    path : path
        The package to write (``.ssp``).
    reference : controllers.trajectory.Reference
        The manoeuvre the controller plays; the run lasts its time grid.
    limits : sequence of float, optional
        Torque saturation per actuated joint (default: the design's).
    schedule : controllers.schedule.Schedule, optional
        A gain schedule of ``d`` over the path: the controller interpolates its matrices along it
        (:class:`ScheduledPredictiveLQGLaw`).
    integral : controllers.integral.IntegralDesign or controllers.integral.ScheduledIntegral, optional
        Integral action on the joint positions (:func:`controllers.integral.design_integral` of ``d``): the
        controller is :class:`PredictiveIntegralLQGLaw`; with ``schedule``, its
        :func:`controllers.integral.design_scheduled_integral`: :class:`ScheduledPredictiveIntegralLQGLaw`.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from fmpy.ssp.ssd import read_ssd

    from controllers.export import export_controller_fmu

    path = Path(path)
    if path.suffix != ".ssp":
        raise DesignError(f"--export-ssp {path}: expected a file name ending in .ssp")
    with tempfile.TemporaryDirectory(prefix="flexlink-ssp-") as tmp:
        root = Path(tmp)
        (root / "resources").mkdir()
        shutil.copy(plant_fmu, root / "resources" / f"{PLANT}.fmu")
        export_controller_fmu(d, root / "resources" / f"{CONTROLLER}.fmu", limits=limits, reference=reference,
                              delay=1, schedule=schedule, duration=reference.duration, integral=integral)
        ssd = system_structure(d.plant.model.scene.name, list(d.kalman.sensors), list(d.lqr.inputs), d.dt,
                               float(reference.time[-1]))
        (root / "SystemStructure.ssd").write_text(ssd)
        staged = root / "system.ssp"
        with zipfile.ZipFile(staged, "w", zipfile.ZIP_DEFLATED) as z:
            for f in ("SystemStructure.ssd", f"resources/{PLANT}.fmu", f"resources/{CONTROLLER}.fmu"):
                z.write(root / f, f)
        read_ssd(str(staged), validate=True)          # raises with the schema's messages
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(staged, path)
        except OSError as e:
            raise DesignError(f"--export-ssp {path}: cannot write the file ({e.strerror})") from None
    return path


class JacobiDelay:
    """A law as a Jacobi co-simulation master applies it: one sample late.

    The torque it returns at sample k is the wrapped law's from sample k−1, and ``u_init`` at sample 0.
    """

    def __init__(self, law: Any, u_init: Sequence[float] | np.ndarray):
        self.law, self.u_init = law, np.asarray(u_init, dtype=float)
        self.dt, self.sensors, self.inputs, self.kind = law.dt, law.sensors, law.inputs, law.kind

    def reset(self) -> None:
        """Reset the wrapped law; the torque held before the first sample is ``u_init``."""
        self.law.reset()
        self.held = self.u_init.copy()

    def step(self, y: np.ndarray, x_ref: np.ndarray, u_ff: np.ndarray) -> np.ndarray:
        """The torque the law returned a sample ago; sample k is given to the law now."""
        u, self.held = self.held, np.array(self.law.step(y, x_ref, u_ff), dtype=float)
        return u


class JacobiLoop(FmuLoop):
    """:class:`controllers.cosim.FmuLoop` stepping the plant as libcosim's Jacobi master steps a connected system.

    Two things of libcosim's fixed-step algorithm, so that the two masters' runs agree bit for bit:

    * It transfers the controller's initial output to the plant's inputs while it initialises
      (``fixed_step_algorithm::initialize``: each simulator's ``setup``, iterations of transfers,
      ``start_simulation``), so the plant leaves initialisation with that torque applied (its outputs at t_0,
      and the start of its integrator, see it; the tip accelerometer reads it).  Here the plant's torque
      inputs are set to a :class:`JacobiDelay` law's ``u_init`` before its initialisation ends.
    * Its time is integer nanoseconds: step k is ``fmi2DoStep(t_k, t_k+1 − t_k)`` with ``t_k = k Δ / 10⁹`` in
      double (Δ the step in ns), not ``(k h, h)``.  The plant's integrator sees the step size's last bits, and
      the accelerometer LQG's loop carries such differences on (docs/control.md), so this loop steps the plant
      on that grid too.
    """

    #: libcosim's time unit per second (``cosim::time_point`` counts nanoseconds)
    TICKS = 1_000_000_000

    def run(self, law: JacobiDelay, reference: Reference, **kw: Any) -> LoopResult:  # type: ignore[override]
        """:meth:`FmuLoop.run` with the torque ``law.u_init`` on the plant before the first sample."""
        self._held = (list(law.inputs), np.asarray(law.u_init, dtype=float))
        stepped: Any = law                    # FmuLoop steps any law with sensors, inputs, reset() and step()
        return super().run(stepped, reference, **kw)

    def _initialise(self, params: Mapping[str, float]) -> None:
        names, values = self._held          # set before initialisation ends: the plant starts with it applied
        super()._initialise({**params, **{n: float(v) for n, v in zip(names, values, strict=True)}})
        s = self.slave
        if getattr(s, "_jacobi_raw_step", None) is None:    # once per instance: the loop fetches it each run
            s._jacobi_raw_step = s.fmi2DoStep
            s.fmi2DoStep = self._libcosim_step

    def _libcosim_step(self, component: Any, t: float, h: float, no_set_prior: int) -> int:
        """``fmi2DoStep`` of sample ``k = t / h`` on libcosim's nanosecond grid (class docstring)."""
        ticks = int(h * self.TICKS)                 # cosim::to_duration: truncated to whole nanoseconds
        k = round(t / h)
        t0, t1 = (k * ticks) / self.TICKS, ((k + 1) * ticks) / self.TICKS
        return self.slave._jacobi_raw_step(component, t0, t1 - t0, no_set_prior)


class PredictiveLQGLaw(MimoLQGLaw):
    """The sampled LQG for a loop that applies its torque one sample late.

    :class:`MimoLQGLaw` for a loop that applies its torque one sample late (``DELAY 1`` in
    ``ctrl_fmu.c``): at sample k the estimate corrected with y_k is predicted to k+1 with the torque v_k being
    applied (its own previous output), and the torque returned is the next sample's,
    ``sat(u₀ + u_ff,k+1 − K_d ẑ_k+1)``.  ``initial()``: the torque before the first sample, u₀ + u_ff,0.
    """

    def __init__(self, d: ControlDesign, limits: Sequence[float], reference: Reference, prediction: str = "model"):
        self.u_ff = reference.u_ff
        super().__init__(d, limits, reference, prediction)

    def initial(self) -> np.ndarray:
        """The torque before the first sample: u₀ + u_ff,0, saturated (the FMU's output before its first step)."""
        return np.clip(self.u0 + self.u_ff[0], -self.limits, self.limits)

    def reset(self) -> None:
        """Sample 0 next, the initial torque being applied and held while y_0 is sampled.

        A Jacobi master connects the controller's initial output to the plant during initialisation
        (libcosim's ``fixed_step_algorithm::initialize``), so the plant's outputs at t_0 see it (:class:`JacobiLoop`).
        """
        super().reset()
        self.v = self.initial()
        self.u_prev = self.v - self.u0

    @checked_step
    def step(self, y: np.ndarray, x_ref: np.ndarray, u_ff: np.ndarray) -> np.ndarray:
        """Sample k: correct and predict with sample k's matrices, return sample k+1's torque (its gain).

        With the tip accelerometer the correction and prediction are :class:`MimoLQGLaw`'s along the reference
        (its measurement model — the model's outputs at the estimate — with the torque held while y_k was
        sampled, the plant and Kalman gain sampled along the reference).
        """
        M, C, _, Ad, Bd = self.matrices(self.k)
        W = self.W
        if self.along is not None and self.k < len(self.along.M):
            M, Ad, Bd, W = self.along.M[self.k], self.along.A[self.k], self.along.B[self.k], self.along.W
            dx = self.finite(self.dz + M @ (y - self.predicted(x_ref, C)))
        else:
            dx = self.dz + M @ (y - self.y0 - C @ (x_ref + self.dz))
        self.dz = self.finite(Ad @ dx + Bd @ (self.v - self.u0 - u_ff) - W[min(self.k, len(W) - 1)])
        self.u_prev = self.v - self.u0              # held while y_k+1 is sampled
        self.k += 1
        nxt = min(self.k, len(self.u_ff) - 1)
        self.v = np.clip(self.u0 + self.u_ff[nxt] - self.matrices(self.k)[2] @ self.dz, -self.limits, self.limits)
        return self.v.copy()


class ScheduledPredictiveLQGLaw(PredictiveLQGLaw):
    """The predictive LQG with a gain schedule's matrices.

    :class:`PredictiveLQGLaw` with the matrices of a gain schedule (:class:`controllers.schedule.
    ScheduledLQGLaw`'s, at the reference's path parameter): sample k corrects and predicts with sample k's
    matrices and its torque for sample k+1 takes sample k+1's gain, as ``ctrl_fmu.c`` with ``DELAY 1`` and
    ``NSCHED > 0`` does.
    """

    kind = "scheduled"

    def __init__(self, schedule: Schedule, limits: Sequence[float], reference: Reference, prediction: str = "model"):
        from controllers.schedule import ScheduledLQGLaw

        self.scheduled = ScheduledLQGLaw(schedule, limits, reference, prediction)
        super().__init__(schedule.designs[0], limits, reference, prediction)
        self.W = self.scheduled.W

    def matrices(self, k: int) -> tuple[np.ndarray, ...]:
        """The schedule's (M, C, K_d, A_d, B_d) at sample ``k`` (the last sample's after the reference)."""
        return self.scheduled.matrices(min(k, len(self.u_ff) - 1))


class PredictiveIntegralLQGLaw(PredictiveLQGLaw):
    """The predictive LQG with integral action on the joint positions, for a loop one sample late.

    :class:`PredictiveLQGLaw` with the augmented design of :func:`controllers.integral.design_integral`
    (``DELAY 1`` with ``INTEGRAL 1`` in ``ctrl_fmu.c``): at sample k the estimate is corrected with y_k and
    predicted to k+1 with the torque v_k being applied; the joints' error integrals ξ take sample k's measured
    encoder errors unless v_k saturates (the anti-windup of :class:`controllers.integral.IntegralLQGLaw`, on
    the torque applied over the sample); the torque returned is sample k+1's, ``sat(u₀ + u_ff,k+1 − K_ξ ξ_k+1
    − K_x ẑ_k+1)``.  Sensors linear in the state only (encoders, strain gauges).
    """

    def __init__(self, integral: IntegralDesign, limits: Sequence[float], reference: Reference):
        self.Kx, self.Ki, self.rows = integral.Kx, integral.Ki, list(integral.rows)
        super().__init__(integral.design, limits, reference, "linear")
        if self.schedule is not None:
            raise DesignError("integral action: the sensors read the torques (accelerometers); use the strain gauges")
        self.Ce = self.C[self.rows]

    def reset(self) -> None:
        """As :meth:`PredictiveLQGLaw.reset`, the integrals at zero."""
        self.xi = np.zeros(len(self.Ki))
        super().reset()

    def matrices(self, k: int) -> tuple[np.ndarray, ...]:
        """(M, C, K_x, A_d, B_d): the LQG's, with the augmented design's state gain."""
        M, C, _, Ad, Bd = super().matrices(k)
        return M, C, self.Kx, Ad, Bd

    def integral_gain(self, k: int) -> np.ndarray:
        """K_ξ of sample ``k``: the design's (a scheduled law overrides this)."""
        return self.Ki

    @checked_step
    def step(self, y: np.ndarray, x_ref: np.ndarray, u_ff: np.ndarray) -> np.ndarray:
        """Sample k: correct, predict with the torque applied, integrate, return sample k+1's torque."""
        M, C, _, Ad, Bd = self.matrices(self.k)
        dx = self.dz + M @ (y - self.y0 - C @ (x_ref + self.dz))
        self.dz = self.finite(Ad @ dx + Bd @ (self.v - self.u0 - u_ff) - self.W[min(self.k, len(self.W) - 1)])
        self.u_prev = self.v - self.u0
        if np.all(np.abs(self.v) < self.limits):        # conditional integration on the torque applied now
            self.xi = self.xi + self.dt * (np.asarray(y)[self.rows] - self.y0[self.rows] - self.Ce @ x_ref)
        self.k += 1
        nxt = min(self.k, len(self.u_ff) - 1)
        Kx = self.matrices(self.k)[2]                   # the next sample's gains (a schedule's at k+1)
        u = self.u0 + (self.u_ff[nxt] - self.integral_gain(self.k) @ self.xi) - Kx @ self.dz
        self.v = np.clip(u, -self.limits, self.limits)
        return self.v.copy()


class ScheduledPredictiveIntegralLQGLaw(PredictiveIntegralLQGLaw):
    """The predictive LQG with integral action and a gain schedule, for a loop one sample late.

    :class:`PredictiveIntegralLQGLaw` with the matrices of
    :class:`controllers.integral.ScheduledIntegralLQGLaw` (K_x and K_ξ included) at the reference's path
    parameter: sample k corrects, predicts and integrates with sample k's matrices, and its torque for sample
    k+1 takes sample k+1's K_x and K_ξ, as ``ctrl_fmu.c`` with ``DELAY 1``, ``INTEGRAL 1`` and ``NSCHED > 0``
    does.
    """

    kind = "scheduled"

    def __init__(self, integral: ScheduledIntegral, limits: Sequence[float], reference: Reference):
        from controllers.integral import ScheduledIntegralLQGLaw

        self.scheduled = ScheduledIntegralLQGLaw(integral, limits, reference)
        super().__init__(integral.designs[0], limits, reference)
        self.W = self.scheduled.W

    def matrices(self, k: int) -> tuple[np.ndarray, ...]:
        """The schedule's (M, C, K_x, A_d, B_d) at sample ``k`` (the last sample's after the reference)."""
        return self.scheduled.matrices(min(k, len(self.u_ff) - 1))

    def integral_gain(self, k: int) -> np.ndarray:
        """The schedule's K_ξ at sample ``k`` (the last sample's after the reference)."""
        return self.scheduled.integral_gain(min(k, len(self.u_ff) - 1))
