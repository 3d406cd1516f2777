"""Closed-loop co-simulation: a sampled control law drives the FMU through fmpy's low-level ``FMU2Slave``.

One :class:`FmuLoop` extracts and instantiates the FMU once; each :meth:`FmuLoop.run` resets it
(``fmi2Reset``) when it has run before, sets the parameters, initialises, then at every sample::

    y_k = getReal(outputs)                 (outputs at t_k, the torque u_{k−1} still applied)
    u_k = law.step(y_k, x_ref[k], u_ff[k]) (saturated)
    setReal(<joint>.tau, u_k); doStep(t_k, dt)     (every actuated joint's torque: law.inputs)

and returns the recorded outputs as named time series (:class:`LoopResult`).  Two loops do this, the same
run up to rounding (tests/test_control_fmu.py):

* :meth:`FmuLoop._run_affine` — for a law with an :class:`~controllers.laws.AffineForm` (the LQG without a
  measurement schedule, the PD) and no sensor noise: one ``numpy.dot`` per sample and the FMU's own
  functions called through cffi on pointers made once (issue 22: fmpy's wrappers, numpy on tiny arrays and
  then ctypes' per-call conversions were most of a sample's time);
* :meth:`FmuLoop._run_stepped` — any law (multi-joint, scheduled, noisy): ``law.step`` per sample on fmpy's
  ctypes functions and value arrays allocated once.

The instance lives on one :class:`flexlink.run.host.FmuHost` (extraction, the log router, initialisation,
clean-up, the raw functions of the fast loop); errors the FMU reports reach the caller as
:class:`FmuLoopError` (the host's :class:`~flexlink.run.host.FmuCallError`) with the FMU's own log messages.
"""

from __future__ import annotations

import ctypes
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from fmpy.fmi1 import FMICallException

from controllers.laws import AffineForm, SampledLaw
from controllers.trajectory import Reference
from flexlink.errors import FlexlinkError
from flexlink.run.host import FmuCallError, FmuHost, pointer

__all__ = ["FmuLoop", "FmuLoopError", "LoopResult"]


#: A call the FMU refused during a closed-loop run: :class:`flexlink.run.host.FmuCallError` (the call, its status,
#: the FMU's logged reason and, for a sample, the step and time at which it failed).
FmuLoopError = FmuCallError


@dataclass
class LoopResult:
    """Named time series of one closed-loop run, plus the wall-clock time of the run.

    ``series["time"]``, the outputs by FMU name and the torque under the input's name; the wall time excludes
    instantiation and the FMU's build, so that it measures the loop alone.
    """

    series: dict[str, np.ndarray]
    wall_time: float
    parameters: dict[str, float] = field(default_factory=dict)
    cpu_time: float | None = None       # this process's CPU time over the same span (a loaded machine's
                                        # wall time includes the time the loop waited for a core)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.series[name]

    @property
    def time(self) -> np.ndarray:
        """The sample times, s (``series["time"]``)."""
        return self.series["time"]

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall-clock second."""
        return float(self.time[-1] - self.time[0]) / self.wall_time if self.wall_time > 0 else float("inf")


class FmuLoop:
    """An FMU instantiated once for repeated closed-loop runs.

    Parameters
    ----------
    fmu : path
        A Co-Simulation FMU (FMI 2.0).
    record : list of str, optional
        Outputs to record besides the law's sensors (FMU names).
    instance_name : str, optional

    Examples
    --------
    >>> with FmuLoop("rotating_link.fmu", record=["arm.tip.v"]) as loop:   # doctest: +SKIP
    ...     res = loop.run(law, reference)
    ...     res2 = loop.run(law, reference, parameters={"arm.payload.mass": 0.65})
    """

    def __init__(self, fmu: str | os.PathLike, record: Sequence[str] = (), instance_name: str = "flexlink_loop"):
        self.host = FmuHost(fmu, interface="CoSimulation", instance_name=instance_name)
        self.path = self.host.path
        self.md = self.host.model_description
        self.variables = self.host.variables
        self.record = list(record)

    @property
    def slave(self):
        """The fmpy ``FMU2Slave`` of the host (for loops that call it directly)."""
        return self.host.instance

    @property
    def messages(self) -> list[str]:
        """What the FMU logged, in order (FMI printf formats: ``%%`` for a percent sign)."""
        return self.host.messages

    def vr(self, name: str) -> int:
        """The value reference of ``name`` (an unknown name: a :class:`FlexlinkError` naming close ones)."""
        return self.host.value_reference(name)

    def close(self) -> None:
        """Terminate and free the instance and its library (once), delete the extracted files."""
        self.host.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -------------------------------------------------------------------------------------- a run
    def run(self, law: SampledLaw, reference: Reference, parameters: Mapping[str, float] | None = None,
            solver_step: float | None = None, noise: Mapping[str, float] | None = None,
            seed: int = 0, fast: bool = True) -> LoopResult:
        """Run ``law`` against the FMU along ``reference`` (its time grid, its sample time).

        Parameters
        ----------
        law : SampledLaw or a multi-joint law (:mod:`controllers.multijoint`)
            ``sensors``, ``dt``, ``inputs`` (or one ``input``), ``reset()``, ``step(y, x_ref, u_ff)`` → the
            torque(s); reset before the run.
        reference : Reference
            ``x_ref`` and ``u_ff`` per sample; the run lasts ``reference.time[-1]``.
        parameters : dict, optional
            FMU parameters to set before initialisation (e.g. ``{"arm.payload.mass": 0.65}``).
        solver_step : float, optional
            ``solver.step`` (internal SS22 step); default: the FMU's own.
        noise : dict, optional
            Sensor name → standard deviation of white Gaussian noise added to what the law reads (the
            recorded outputs stay noise-free), e.g. :data:`controllers.design.SENSOR_NOISE` levels.
        seed : int
            Seed of the noise generator.
        fast : bool
            Run a law that has an :meth:`~controllers.laws.SampledLaw.affine` form (and no noise) as one
            matrix product per sample on raw ctypes calls (:meth:`_run_affine`); False: always the reference
            loop that calls ``law.step`` (:meth:`_run_stepped`), the same run up to rounding.
        """
        dt = reference.dt
        if abs(law.dt - dt) > 1e-12:
            raise ValueError(f"the law samples at {law.dt} s but the reference at {dt} s")
        params = dict(parameters or {})
        if solver_step is not None:
            params["solver.step"] = solver_step
        for name in params:
            v = self.variables.get(name)
            if v is None or v.causality != "parameter":
                raise FlexlinkError(f"{name}: not a parameter of {os.path.basename(self.path)}")
        sensors = list(law.sensors)
        unknown = set(noise or {}) - set(sensors)
        if unknown:
            raise FlexlinkError(f"noise on {sorted(unknown)}: not sensors of the law ({sensors})")
        names = list(dict.fromkeys([*sensors, *self.record]))
        inputs = list(getattr(law, "inputs", None) or [law.input])
        law.reset()
        form = law.affine(reference) if fast and not noise and hasattr(law, "affine") else None
        vr_out = (ctypes.c_uint * len(names))(*[self.vr(n) for n in names])
        vr_in = (ctypes.c_uint * len(inputs))(*[self.vr(n) for n in inputs])

        t0, c0 = time.perf_counter(), time.process_time()
        self._initialise(params)
        try:
            if form is not None:
                Y, U = self._run_affine(form, [names.index(n) for n in sensors], vr_out, vr_in, reference)
            else:
                Y, U = self._run_stepped(law, [names.index(n) for n in sensors], vr_out, vr_in, reference,
                                         noise, seed)
        finally:
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        self.host.call("fmi2Terminate", self.slave.terminate)
        series = {"time": reference.time.copy()}
        for i, name in enumerate(names):
            series[name] = Y[:, i].copy()
        for i, name in enumerate(inputs):
            series[name] = U[:, i].copy()
        return LoopResult(series, wall, params, cpu)

    def _initialise(self, params: Mapping[str, float]) -> None:
        """Reset (after a first run), set the parameters (each with its type's setter), initialise."""
        self.host.initialize(params)

    def _step_failed(self, k: int, dt: float, e: FMICallException) -> FmuCallError:
        return self.host.refusal(e.function, e.status, where=f"step {k} (t = {k * dt:.6g} s)")

    def _run_stepped(self, law, sensor_idx: list[int], vr_out, vr_in, reference: Reference, noise, seed: int):
        """The reference loop: fmpy's ctypes functions on arrays allocated once, ``law.step`` per sample."""
        s, dt = self.slave, reference.dt
        n_out, m, p = len(vr_out), len(vr_in), len(sensor_idx)
        val_out, val_in = (ctypes.c_double * n_out)(), (ctypes.c_double * m)()
        u_in = np.ctypeslib.as_array(val_in)                    # a view: fmi2SetReal reads it in place
        n_steps = len(reference.time) - 1
        sensors = list(law.sensors)
        sigma = np.array([float((noise or {}).get(n, 0.0)) for n in sensors])
        E = np.random.default_rng(seed).standard_normal((n_steps + 1, p)) * sigma if noise else None
        Y, U = np.empty((n_steps + 1, n_out)), np.empty((n_steps + 1, m))
        x_ref, u_ff = reference.x, reference.u_ff
        comp = s.component
        get_real, set_real, do_step = s.fmi2GetReal, s.fmi2SetReal, s.fmi2DoStep
        k = 0
        y = np.ctypeslib.as_array(val_out)                    # a view: fmi2GetReal refills it in place
        prefix = sensor_idx == list(range(p))                 # the sensors come first: a slice, not a copy
        try:
            for k in range(n_steps + 1):
                get_real(comp, vr_out, n_out, val_out)
                Y[k] = y
                if E is not None:
                    ys = y[sensor_idx] + E[k]
                else:
                    ys = y[:p] if prefix else y[sensor_idx]
                u = law.step(ys, x_ref[k], u_ff[k])
                U[k] = u
                if k == n_steps:
                    break
                u_in[:] = u
                set_real(comp, vr_in, m, val_in)
                do_step(comp, k * dt, dt, 1)
        except FmuCallError:
            raise                  # a law on an FMU of its own (controllers.export.FmuLaw) reports its own refusal
        except FMICallException as e:
            raise self._step_failed(k, dt, e) from None
        return Y, U

    def _run_affine(self, form: AffineForm, sensor_idx: list[int], vr_out, vr_in, reference: Reference):
        """The fast loop (issue 22): per sample the FMU's three functions through cffi and one ``numpy.dot``.

        Everything of a sample lives in one row of ``H`` = (outputs y_k, law state s_k, u_{k−1}, 1):
        ``fmi2GetReal`` writes y_k straight into row k, ``G @ H[k]`` writes (s_{k+1}, v_k) into row k+1,
        the clipped torque overwrites v_k there and ``fmi2SetReal`` reads it from there.  The recorded
        outputs and torques are columns of ``H``: nothing is copied or allocated per sample (the rows' views
        and their C pointers are made once, before the first sample).
        """
        dt, n_out, ns = reference.dt, len(vr_out), form.n_state
        n_steps = len(reference.time) - 1
        iu = n_out + ns                                        # column of u_{k−1}
        G = np.zeros((ns + 1, iu + 2))
        G[:, sensor_idx] = form.Gy
        G[:, n_out:iu] = form.Gs
        G[:, iu], G[:, iu + 1] = form.gu, form.g1
        H = np.zeros((n_steps + 2, iu + 2))
        H[:, iu + 1] = 1.0
        H[0, iu] = form.u0
        get_real, set_real, do_step = (self.host.raw(f) for f in ("fmi2GetReal", "fmi2SetReal", "fmi2DoStep"))
        comp = pointer(self.slave.component, "void")
        h = pointer(H.ctypes.data, "double")
        y_at = [h + k * (iu + 2) for k in range(n_steps + 1)]           # &H[k, 0]
        u_at = [h + (k + 1) * (iu + 2) + iu for k in range(n_steps)]    # &H[k + 1, iu]
        p_vr_out, p_vr_in = pointer(ctypes.addressof(vr_out), "unsigned int"), pointer(ctypes.addressof(vr_in),
                                                                                       "unsigned int")
        r, hi = form.r.tolist(), form.limit
        lo, dot = -hi, np.dot
        rows, outs = list(H), list(H[1:, n_out:iu + 1])      # views made in C once, not per sample
        k = 0
        try:
            for k in range(n_steps + 1):
                st = get_real(comp, p_vr_out, n_out, y_at[k])
                if st > 1:
                    raise FMICallException("fmi2GetReal", st)
                out = outs[k]
                dot(G, rows[k], out=out)
                u = out[ns] + r[k]
                out[ns] = hi if u > hi else (lo if u < lo else u)
                if k == n_steps:
                    break
                st = set_real(comp, p_vr_in, 1, u_at[k])
                if st > 1:
                    raise FMICallException("fmi2SetReal", st)
                st = do_step(comp, k * dt, dt, 1)
                if st > 1:
                    raise FMICallException("fmi2DoStep", st)
        except FMICallException as e:
            raise self._step_failed(k, dt, e) from None
        return H[:-1, :n_out], H[1:, iu:iu + 1]
